#pragma once
// The preparation stage: everything the fit needs from the input clip before it starts,
// measured once and stored in the project's prep/ folder.
//   flow      forward/backward DIS optical flow with a consistency mask   (prepare/flow.h)
//   motion    per-frame homography to a reference frame                   (prepare/motion.h)
//   masks     foreground masks, given or automatic                        (prepare/masks.h)
//   coc       initial circle-of-confusion radius map per frame (px)       (prepare/coc.h)
//   decisions what the fit can skip for this clip, with the log lines that explain it
//
// prep/ layout (all sequences numbered from 0):
//   flow_fwd_%04d.exr  t in [0, T−1): float RGB = (u, v, consistent) of the flow t → t+1
//   flow_bwd_%04d.exr  t in [0, T−1): float RGB = (u, v, consistent) of the flow t+1 → t
//   mask_%04d.png      t in [0, T):   8-bit grey foreground mask (1 = subject), no sRGB curve
//   coc_%04d.exr       t in [0, T):   float grey radius in px
//   prepare.json       version, clip size, homographies (row-major 3x3, frame t → reference),
//                      per-pair sources, decisions, log; written last, so its presence means
//                      the folder is complete.
#include <optional>
#include <string>
#include <vector>

#include "io/image.h"
#include "prepare/coc.h"
#include "prepare/flow.h"
#include <functional>

#include "prepare/log.h"
#include "prepare/masks.h"
#include "prepare/motion.h"

namespace refocus {

struct Project;

struct PrepareOptions {
    FlowOptions flow;
    MotionOptions motion;
    MaskOptions mask;
    CocOptions coc;
    std::string mask_path;            // user masks (pattern/folder); empty = automatic
    bool estimate_coc = true;         // false when the fit gets radius maps from --coc
    bool temporal_coc = true;         // (1,2,1) smoothing of the radius along the flow
    double subject_min_frac = 0.001;  // mask area share (over the clip) below which: no subject
    double sharp_radius_px = 0.5;     // a pixel needs no blur taps below this radius
    // A frame is "already sharp" if this share of pixels is below sharp_radius_px. 0.9, not
    // 0.95: the estimator reads 92.5% of a perfectly sharp test frame below 0.5 px (corners
    // and close edges read up to ~1 px).
    double sharp_frame_frac = 0.9;
    // The clip's size when the frames are proxies (proxy.h): given masks come at this size and
    // are shrunk to the frames'. 0: the frames' size.
    int full_width = 0, full_height = 0;
    // Called on a thread of its own once the flow is made, while the later stages run (the fit
    // writes the flow's files there: GrabCut, in the masks, leaves a core free); prepare_clip
    // waits for it, and rethrows what it throws, before it returns.
    std::function<void(const ClipFlow&)> flow_ready;
};

// What the fit may skip, decided per clip.
struct PrepareDecisions {
    bool static_camera = false;     // homographies ≈ identity: no learned background warp
    bool has_subject = true;        // a foreground layer is needed
    std::vector<char> frame_sharp;  // [t]: radius < sharp_radius_px almost everywhere
    bool all_sharp = false;         // every frame sharp: no deconvolution needed
};

struct PrepareResult {
    int width = 0, height = 0, frames = 0;
    ClipFlow flow;
    CameraMotion motion;
    std::vector<Image> masks;  // [t] 1-channel in [0,1]
    std::string mask_source;   // "auto" or the user path
    std::vector<Image> coc;    // [t] 1-channel radius px; empty if !estimate_coc
    PrepareDecisions decisions;
    std::vector<std::string> log;  // every line logged, in order
};

// Runs the stage on linear RGB frames of one size (at least 1): the clip's, or a proxy's
// (proxy.h), and the result is at that size.
PrepareResult prepare_clip(const std::vector<Image>& frames, const PrepareOptions& opts,
                           PrepareLog& log);

// prep/ of the project.
std::string prepare_dir(const Project& project);
// Writes prep/ (every file atomically, prepare.json last), at the size it was made at: the
// project's or its proxy's for some proxy width. load_prepare reads either back.
// `flow_saved`: save_prepare_flow wrote the flow's files already.
void save_prepare(const Project& project, const PrepareResult& result, bool flow_saved = false);
// The flow's files of a preparation of width × height (the first part of save_prepare, which
// then need not write them); the folder's prepare.json goes first.
void save_prepare_flow(const Project& project, const ClipFlow& flow, int width, int height);
// Reads and validates prep/ against the project (counts, sizes, channels); refocus::Error
// names the file and what is wrong.
PrepareResult load_prepare(const Project& project);
// Whether prep/prepare.json exists.
bool has_prepare(const Project& project);

}  // namespace refocus
