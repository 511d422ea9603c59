#pragma once
// The Focus tab: the lens at the playhead, keyframes, click-to-focus and point tracking. The
// actions below are also the script's ("key", "focus_click", "track_click"). Each finished
// change is one entry of the document's undo history (StudioDoc::commit).
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
    const char* tip;  // what the parameter does, for tooltips
};
const std::vector<LaneInfo>& focus_lanes();
// The index into focus_lanes() of a lane's UI or project.json name ("rim", "beta", ...); throws
// naming it when there is none.
int focus_lane_index(const std::string& name);

// The easings as the UI offers them, with their labels ("ease in-out").
struct EasingChoice {
    Easing easing;
    const char* label;
};
const std::vector<EasingChoice>& easing_choices();
const char* easing_label(Easing e);

struct FocusPanelState {
    Easing new_key_easing = Easing::EaseInOut;
};

// Keys `lane` (a focus_lanes() name, or its project.json name) at `frame`; the caller commits
// (a slider keys every frame of its drag and commits once, when it is let go).
void set_focus_key(StudioContext& ctx, const std::string& lane, int frame, double value, Easing e);
// Keys the focus at the depth under image pixel (x, y) of `frame` (click-to-focus).
void focus_at_pixel(StudioContext& ctx, Easing e, int frame, int x, int y);
// Makes the focus follow the atlas point under image pixel (x, y) of `frame`.
void track_pixel(StudioContext& ctx, Easing e, int frame, int x, int y);

void draw_focus_panel(FocusPanelState& s, ViewerState& viewer, StudioContext& ctx);

}  // namespace refocus
