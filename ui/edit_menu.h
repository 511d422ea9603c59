#pragma once
// The Edit menu and its shortcuts: undo and redo of the document's focus changes (keys, their
// easing and values, the tracked point; StudioDoc's history). The atlas editor keeps its own
// undo for strokes: while it is shown, Ctrl+Z is its.

namespace refocus {

struct StudioContext;

// Undo or redo the document's last change; false when there is none.
bool undo_document(StudioContext& ctx);
bool redo_document(StudioContext& ctx);
// Inside the main menu bar.
void draw_edit_menu(StudioContext& ctx);
// Each frame, before the panels: Ctrl+Z, Ctrl+Shift+Z and Ctrl+Y (unless the atlas editor is
// shown or a text field has the keyboard), and a change left open while no control is held
// becomes one undo entry (so that nothing escapes the history).
void handle_edit_keys(StudioContext& ctx, bool atlas_shown);

}  // namespace refocus
