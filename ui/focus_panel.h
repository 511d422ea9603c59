#pragma once
// The Focus tab: the lens at the playhead, keyframes, click-to-focus and point tracking. The
// actions below are also the script's ("key", "focus_click", "track_click").
#include <string>
#include <vector>

#include "edit/focus.h"

namespace refocus {

struct StudioContext;
struct ViewerState;

// One animated focus parameter as the UI lists it (the Focus tab's sliders, the timeline's lanes).
struct LaneInfo {
    const char* name;
    Lane FocusTrack::*lane;
    double min, max;
    const char* format;
};
const std::vector<LaneInfo>& focus_lanes();

struct FocusPanelState {
    Easing new_key_easing = Easing::EaseInOut;
};

// Keys `lane` (a focus_lanes() name, or its project.json name) at `frame`.
void set_focus_key(StudioContext& ctx, const std::string& lane, int frame, double value, Easing e);
// Keys the focus at the depth under image pixel (x, y) of `frame` (click-to-focus).
void focus_at_pixel(StudioContext& ctx, Easing e, int frame, int x, int y);
// Makes the focus follow the atlas point under image pixel (x, y) of `frame`.
void track_pixel(StudioContext& ctx, Easing e, int frame, int x, int y);

void draw_focus_panel(FocusPanelState& s, ViewerState& viewer, StudioContext& ctx);

}  // namespace refocus
