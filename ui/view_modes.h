#pragma once
// The viewer's modes, one row each in view_modes() (view_modes.cpp): its name, its shortcut,
// what it needs and how its picture is made. The menus, the mode bar, the split wipe's sides
// and the script all list from that table, so that adding a mode is adding a row.
// Pictures are made on the viewer's render thread (view_renderer.h), never on the UI thread.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "edit/depth.h"
#include "edit/focus.h"
#include "io/image.h"
#include "preview_backend.h"
#include "studio/fit_worker.h"

namespace refocus {

// What the document says the viewer should show, as the UI thread last posted it. Every change
// that alters a picture (keys, lens, depth, edits, the fit's atlases) bumps `generation`; a
// change of the fit's atlases also bumps `maps_generation` (the per-frame layers change).
struct ViewScene {
    uint64_t generation = 1, maps_generation = 1;
    bool fitted = false;  // the worker has a fit whose frames it can render
    FocusTrack focus;
    std::shared_ptr<const DepthModel> depth;
    EditAtlases edits;
};

// One picture's inputs. `scale` < 1 is the progressive first pass: maps and input come
// downsampled and the lens's radii are scaled with them.
struct ModeInput {
    int frame = 0;
    const Image& input;                // linear RGB
    const FitWorker::ViewFrame* view;  // the fit's layers at `frame`; null: not fitted (yet)
    const ViewScene& scene;
    double scale = 1.0;
    PreviewBackend& preview;
};

struct ViewModeInfo {
    const char* name;     // View menu, scripts ({"mode": name}), screenshot metadata
    const char* label;    // the viewer's mode bar and the split's side lists
    const char* tooltip;  // the mode bar's
    int key;              // GLFW key that selects it (outside text fields); 0: none
    bool needs_fit;       // shows the fit's output (the input until the fit can render)
    bool refocused;       // seen through the lens: the time slice renders its rows refocused
    bool wipe;            // the split wipe: two other modes side by side (no render of its own)
    // The picture, linear RGB. May throw: the renderer then shows the input and says why.
    Image (*render)(const ModeInput& in);
};

// The modes in the mode bar's order; the first (input) is the viewer's default.
const std::vector<ViewModeInfo>& view_modes();
// The mode called `name`; throws refocus::Error listing the names.
const ViewModeInfo& view_mode(const std::string& name);
int view_mode_index(const ViewModeInfo& m);

}  // namespace refocus
