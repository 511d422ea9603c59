#pragma once
// The "Atlas" window: paint on the fitted atlases and see the edit follow every frame (paper
// Fig. 1). Self-contained Dear ImGui window over a ProjectEdits (engine/edit/atlas_edit.h):
// Background / Foreground tabs, the atlas (sRGB for display, uploaded only when it changed),
// zoom (wheel) and pan (middle or right drag), brush (colour, size, hardness, opacity,
// Paint / Erase / Clone with Alt+click for the source, eyedropper: I key or button), undo/redo
// (buttons, Ctrl+Z, Ctrl+Shift+Z / Ctrl+Y), export and import of a layer through the file
// browser (file_browser.h), the full path written or read shown on the panel's info line.
//
// Use from the UI thread with a current GL context:
//     AtlasPanel panel; panel.set_edits(&edits);
//     panel.set_bases(bg, fg);            // whenever the fit's atlases change
//     if (panel.draw()) document_changed();  // a stroke, an undo, an import
#include <array>
#include <functional>
#include <string>
#include <vector>

#include "edit/atlas_edit.h"
#include "file_browser.h"

namespace refocus {

class AtlasPanel {
  public:
    AtlasPanel() = default;
    ~AtlasPanel();  // deletes its GL textures: destroy it while the context is current
    AtlasPanel(const AtlasPanel&) = delete;
    AtlasPanel& operator=(const AtlasPanel&) = delete;

    void set_edits(ProjectEdits* edits);
    // Optional: enables "Save edits" (edits/edit_*.exr + project.json).
    void set_project(Project* project) { m_project = project; }
    // The fit's atlases (linear RGB); `fg` empty with one layer. The edits are kept.
    void set_bases(const Image& bg, const Image& fg);

    // Draws the window; true when the artist's edits changed since the last draw() (strokes,
    // undo, import, programmatic calls): the document changed. New bases (set_bases) and the
    // edits given to set_edits are not changes.
    bool draw(bool* open = nullptr);

    // Programmatic API (scripts, tests): layer 0 = background, 1 = foreground. Points in atlas
    // px. Return false on failure with the message in error().
    bool paint_stroke(int layer, const std::vector<std::array<float, 2>>& pts_atlas_px,
                      const Brush& brush);
    bool import_atlas(int layer, const std::string& path);
    bool export_atlas(int layer, const std::string& path, PixelFormat format);
    bool undo(int layer);
    bool redo(int layer);
    // What "Export..." and "Import..." do: open the panel's file browser (on `dir` when given);
    // the pick exports or imports the active layer and the info line says the full path.
    void ask_export(const std::string& dir = {});
    void ask_import(const std::string& dir = {});
    FileBrowser& browser() { return m_browser; }  // scripts: pick in it
    const std::string& status() const { return m_status; }

    // Where atlas px (x, y) was drawn by the last draw(), in ImGui screen coordinates.
    std::array<float, 2> atlas_to_screen(float x, float y) const {
        return {m_origin[0] + x * m_scale, m_origin[1] + y * m_scale};
    }
    const std::string& error() const { return m_error; }
    int active_layer() const { return m_layer; }
    void set_active_layer(int layer) { m_layer = layer == 1 ? 1 : 0; }
    Brush& brush() { return m_brush; }

  private:
    AtlasEditor* editor(int layer);
    bool guarded(const std::function<void()>& f);
    void upload(int layer);
    void draw_canvas(AtlasEditor& ed);
    void draw_controls(AtlasEditor& ed);
    void draw_file_buttons();
    void take_browser_pick();

    ProjectEdits* m_edits = nullptr;
    Project* m_project = nullptr;
    int m_layer = 0;
    Brush m_brush;
    std::string m_error;
    int64_t m_reported[2] = {-1, -1};  // version last reported by draw()

    unsigned m_tex[2] = {0, 0};
    int64_t m_tex_version[2] = {-1, -1};
    float m_zoom = 1.0f, m_pan[2] = {0, 0};      // zoom relative to fit-in-window
    float m_origin[2] = {0, 0}, m_scale = 1.0f;  // last drawn: screen = origin + atlas px · scale
    bool m_painting = false, m_picking = false;
    bool m_have_clone_src = false, m_clone_aligned = false;
    float m_clone_src[2] = {0, 0};
    int m_export_format = 0;  // PNG 8, TIFF 16, EXR
    FileBrowser m_browser;
    enum class Browsing { None, Import, Export } m_browsing = Browsing::None;
    std::string m_status;  // what the last export or import wrote or read (full path)
};

}  // namespace refocus
