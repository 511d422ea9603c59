#pragma once
// The viewer: the playhead's frame in one of the view modes (view_modes.h), zoom and pan, the
// time slice, and clicks on the image for click-to-focus and tracking. The Atlas panel takes
// its place while it is shown.
#include <optional>

#include "time_slice.h"
#include "view_modes.h"

namespace refocus {

class AtlasPanel;
struct StudioContext;

struct ViewerState {
    const ViewModeInfo* mode = &view_modes().front();
    const ViewModeInfo* split_a = &view_mode("input");  // the split wipe's left side
    const ViewModeInfo* split_b = &view_mode("refocused");
    float split = 0.5f;  // the wipe's place, 0..1 of the width
    float zoom = 0.0f;   // 0: fit the window
    bool show_atlas = false;
    enum class Pick { None, Focus, Track } pick = Pick::None;  // what a click on the image does
    TimeSliceState slice;
    unsigned tex = 0;
    int tex_w = 0, tex_h = 0;
    // The image rectangle last drawn (screen px), for clicks and screenshots.
    float img_x = 0, img_y = 0, img_w = 0, img_h = 0;
};

// A click on the image while a pick was armed, in image px.
struct ViewerClick {
    ViewerState::Pick pick;
    int x, y;
};

void set_view_mode(ViewerState& v, StudioContext& ctx, const ViewModeInfo& mode);
// Takes what the worker delivered (atlases, the playhead's frame, the depth) and asks for
// what the viewer needs next.
void poll_fit_output(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx);
// Renders the current mode at the playhead into the viewer's texture.
void refresh_view(ViewerState& v, StudioContext& ctx);
std::optional<ViewerClick> draw_viewer(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx);
void release_viewer(ViewerState& v);  // its GL textures

}  // namespace refocus
