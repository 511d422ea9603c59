#pragma once
// Foreground masks: 1 on the moving subject (the foreground layer), 0 on the background.
// Either given by the user (one image per frame) or found automatically.
//
// Automatic masks (seed 001 §1.5.1: "register with a homography, threshold the residual, close
// it"), adapted to defocused video. Seed 001 thresholds the intensity difference of registered
// frames; here focus changes from frame to frame too, which makes every edge differ after
// registration, and a flat subject differs only along its outline. So the residual is a flow's:
//  1. Long baselines (baseline_residuals): frame t against frames t ± k (k in `baselines`),
//     each registered onto t by the camera homographies, with DIS flow between them at
//     flow_scale (a low-pass: what a change of focus does to an image is mostly fine detail,
//     and it barely moves what is left). After registration the background's flow is ~0 and
//     the subject's is its own motion over k frames, so that a slow subject stands out of
//     what a change of focus does to the wall's flow.
//     Per baseline, the smaller residual of the two partners where the flow passes the
//     forward-backward test (a background pixel occluded in one partner is not in the other);
//     then the largest over the baselines (a long one breaks down on a fast subject, a short
//     one misses a slow one).
//  2. Adjacent frames (adjacent_residuals): the full-resolution flow t → t ± 1 against the
//     flow the homography predicts. Alone it drowns slow subjects in focus-change noise; it
//     finds what moves several px per frame, which the long baselines can lose.
//  3. threshold_masks: step 1 above Otsu's threshold (never below min_residual_px: the
//     focus-change noise of a locked-off clip stays under it) or step 2 above median + k·MAD
//     (never below adjacent_min_px); closed, holes filled, opened, small components dropped.
//  4. refine_masks: GrabCut to the frame's colour edges (the flow's smoothing fattens the blob
//     by several px).
//  5. vote_masks: each frame's mask becomes the weighted majority of the clip's non-empty masks
//     registered onto it, which fills frames where the subject paused against the background
//     and drops blobs that appear in one frame only; then refined again.
// `refocus bench motion` scores the masks (IoU against the synth clips' true alpha).
// Steps run at most work_width wide; the options' px are px of a 320 px wide frame, scaled.
// Limit: a subject that never moves relative to the background is not separated (it is, for
// the fit, part of the rigid background).
#include <algorithm>
#include <string>
#include <vector>

#include "io/image.h"
#include "prepare/flow.h"
#include "prepare/motion.h"

namespace refocus {

struct MaskOptions {
    int work_width = 480;  // masks are found at most this wide, then upscaled
    std::vector<int> baselines{
        1, 2, 4};              // frame t against frames t ± each of these; the largest residual
    double flow_scale = 0.5;   // ... with the flow at this scale of the working frame,
    int min_flow_width = 160;  // ... but at least this wide
    FlowPreset flow_preset = FlowPreset::Medium;  // Fine follows the focus changes
    double min_residual_px = 1.5;  // threshold: Otsu's, never below this (px over the baseline)
    double adjacent_k_mad = 6.0;   // adjacent frames' residual: median + k·1.4826·MAD, ...
    double adjacent_min_px = 2.5;  // ... never below this (px per frame)
    int close_px = 3;              // closing radius (bridges gaps in the residual)
    int open_px = 1;               // opening radius (removes specks)
    bool fill_holes = true;        // flat subject interiors have little flow residual
    double min_area_frac = 0.002;  // keep components covering at least this share of the frame
    int refine_in_px = 12;         // GrabCut: the mask eroded by this is certain foreground, ...
    int refine_out_px = 6;         // ... a ring this wide around it probable background
    int refine_iters = 3;
    double vote_tau = 1.0;  // vote weight exp(−|s − t| / tau) of frame s's mask; 0: no vote
};

// The whole pipeline above: single-channel 0/1 masks at the frames' size. `residuals`, if
// given, receives step 1's residuals (px, at the working size) to look at.
std::vector<Image> automatic_masks(const std::vector<Image>& frames, const ClipFlow* flow,
                                   const CameraMotion& motion, const MaskOptions& opts = {},
                                   std::vector<Image>* residuals = nullptr);

// The steps, for tests and benchmarks. Step 1 at out_w x out_h; `px` is the working width / 320.
std::vector<Image> baseline_residuals(const std::vector<Image>& frames, const CameraMotion& motion,
                                      int out_w, int out_h, const MaskOptions& opts = {});
std::vector<Image> adjacent_residuals(const ClipFlow& flow, const CameraMotion& motion, int width,
                                      int height);
std::vector<Image> threshold_masks(const std::vector<Image>& residuals,
                                   const std::vector<Image>& adjacent, const MaskOptions& opts,
                                   double px);
std::vector<Image> refine_masks(const std::vector<Image>& frames, const std::vector<Image>& masks,
                                const MaskOptions& opts, double px);
// masks: at any size; the homographies are between full_w x full_h frames.
std::vector<Image> vote_masks(const std::vector<Image>& masks, const CameraMotion& motion,
                              int full_w, int full_h, double tau);

// User masks: `path` is a printf pattern (masks/mask_%04d.png, numbered from 0 or 1), a folder
// of images (natural order) or, for a one-frame clip, one image. Exactly `frames` images of
// width x height are required; errors name the offending file. Grey and RGB masks use their
// mean, RGBA masks their alpha; values are taken as stored (no sRGB decode), clamped to [0,1].
std::vector<Image> load_masks(const std::string& path, int frames, int width, int height);

// The largest radius (px) a --coc map may hold for a width × height clip: half the long side,
// 256 px at most (a disk beyond that is no misfocus a fit can undo, and its cost grows as r²).
inline float max_coc_radius(int width, int height) {
    return std::min(256.0f, 0.5f * float(std::max(width, height)));
}
// Radius maps (px) for `refocus fit --coc`: single-channel (or first channel) float images,
// finite and in 0..max_coc_radius, same rules for count and size as load_masks.
std::vector<Image> load_coc_maps(const std::string& path, int frames, int width, int height);

}  // namespace refocus
