#pragma once
// The timeline's key lanes: one row per focus parameter (focus_lanes()) with its keyframes.
// Click selects a key (Shift+click adds or removes one), dragging moves the selected keys in
// whole frames (kept inside the clip; one undo entry per drag), Delete removes them, Ctrl+C /
// Ctrl+V copy them and paste them at the playhead (their spacing kept), right-click opens a
// key's menu (easing, value, delete), hovering shows its frame, value and easing. Clicking or
// dragging where there is no key moves the playhead.
#include <imgui.h>

#include <string>
#include <utility>
#include <vector>

#include "edit/focus.h"

namespace refocus {

struct StudioContext;

struct KeyRef {
    int lane = 0;  // index into focus_lanes()
    int frame = 0;
    bool operator==(const KeyRef& o) const { return lane == o.lane && frame == o.frame; }
};

struct KeyLaneState {
    std::vector<KeyRef> selected;
    std::vector<std::pair<KeyRef, Keyframe>> clipboard;  // frames relative to the first copied
    // A press on a key: the track and selection then, where the mouse was, how far it moved.
    bool pressed_key = false, scrubbing = false;
    FocusTrack drag_from;
    std::vector<KeyRef> drag_keys;
    float press_x = 0.0f;
    int drag_delta = 0;
    KeyRef pressed;   // the key pressed
    KeyRef menu_key;  // the key whose context menu is open
};

// Moves `keys` of `track` by `delta` frames, clamped so that all stay in 0..frames-1; keys at
// the targets that are not moved are replaced. Returns the keys' new places. Throws
// refocus::Error naming a key that is not there.
std::vector<KeyRef> move_keys(FocusTrack& track, const std::vector<KeyRef>& keys, int delta,
                              int frames);
// Removes the keys that are there; returns how many.
int remove_keys(FocusTrack& track, const std::vector<KeyRef>& keys);

// The script's "move_key" and "delete_key": one key of a lane by name, one undo entry.
void move_key(StudioContext& ctx, const std::string& lane, int from, int to);
void delete_key(StudioContext& ctx, const std::string& lane, int frame);

// Draws the lanes in the rectangle at `origin` of `size` (screen coordinates) of the current
// window, with the playhead and the tracked range, and handles their mouse and keys.
void draw_key_lanes(KeyLaneState& s, StudioContext& ctx, ImVec2 origin, ImVec2 size);

}  // namespace refocus
