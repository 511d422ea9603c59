#pragma once
// The viewer: the playhead's frame in one of the view modes (view_modes.h), zoom and pan, the
// time slice, and clicks on the image for click-to-focus and tracking. The Atlas panel takes
// its place while it is shown.
#include <memory>
#include <optional>
#include <vector>

#include "time_slice.h"
#include "view_modes.h"
#include "view_renderer.h"

namespace refocus {

class AtlasPanel;
struct StudioContext;

struct ViewerState {
    const ViewModeInfo* mode = &view_modes().front();
    const ViewModeInfo* split_a = &view_mode("input");  // the split wipe's left side
    const ViewModeInfo* split_b = &view_mode("refocused");
    float split = 0.5f;  // the wipe's place, 0..1 of the width
    bool dragging_wipe = false;
    float zoom = 0.0f;  // 0: fit the window
    bool show_atlas = false;
    enum class Pick { None, Focus, Track } pick = Pick::None;  // what a click on the image does
    TimeSliceState slice;
    // The pictures on screen: the mode's, and in split mode the right side's.
    struct Picture {
        unsigned tex = 0;
        std::shared_ptr<const RenderedFrame> shown;
    } a, b;
    // The image rectangle last drawn (screen px), for clicks and screenshots.
    float img_x = 0, img_y = 0, img_w = 0, img_h = 0;
};

// A click on the image while a pick was armed, in image px.
struct ViewerClick {
    ViewerState::Pick pick;
    int x, y;
};

void set_view_mode(ViewerState& v, StudioContext& ctx, const ViewModeInfo& mode);
// The modes the viewer shows (view_modes() indexes): the mode, or the split's two sides.
std::vector<int> wanted_modes(const ViewerState& v);
// Takes what the worker delivered (atlases, depth), posts the scene and the playhead to the
// renderer and puts its newest pictures of the playhead on screen.
void poll_fit_output(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx, bool playing);
std::optional<ViewerClick> draw_viewer(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx);
void release_viewer(ViewerState& v);  // its GL textures

}  // namespace refocus
