#pragma once
// The viewer's modes, one row each in view_modes() (view_modes.cpp): its name, its shortcut,
// what it needs and how its picture is made. The menus, the mode bar, the split wipe's sides
// and the script all list from that table, so that adding a mode is adding a row.
#include <string>
#include <vector>

#include "io/image.h"

namespace refocus {

struct StudioContext;
struct ViewerState;

struct ViewModeInfo {
    const char* name;   // View menu, scripts ({"mode": name}), screenshot metadata
    const char* label;  // the viewer's mode bar and the split's side lists
    int key;            // GLFW key that selects it (outside text fields); 0: none
    bool
        needs_fit;  // shows the fit's output: waits for the fit's frame, shows the input until then
    bool refocused;  // seen through the lens: the time slice renders its rows refocused
    bool wipe;       // the split wipe: two other modes side by side, chosen in the mode bar
    // The picture at the playhead, linear RGB. May throw: the viewer then shows the input and
    // says why in the status line.
    Image (*render)(const ViewerState& viewer, StudioContext& ctx);
};

// The modes in the mode bar's order; the first (input) is the viewer's default.
const std::vector<ViewModeInfo>& view_modes();
// The mode called `name`; throws refocus::Error listing the names.
const ViewModeInfo& view_mode(const std::string& name);

}  // namespace refocus
