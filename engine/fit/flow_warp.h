#pragma once
// Residual warps that follow parallax (docs/method.md, Model: parallax within a layer). A layer of
// a 3D scene seen from a moving camera is not carried from frame to frame by one homography: a
// pillar in front of a wall slides across it. The optical flow between neighbouring frames sees
// that slide; these warps make a layer's atlas coordinates agree with it before the fit starts,
// which a warp learned from zero at a fraction of a pixel a step would take hundreds of steps to
// reach.
#include <torch/types.h>

#include <cmath>
#include <functional>
#include <string>

namespace refocus {

struct FlowWarpResult {
    torch::Tensor warp;    // [T,2,gh,gw] frame px, corner-aligned over the frame
    double before_px = 0;  // mean disagreement |A_t(p) − A_{t+1}(p + f)| with no warp
    double after_px = 0;   // ... with the warps
    int64_t points = 0;    // flow correspondences used
};

// The warps w_t minimising, over background pixels p of frame t with a forward-backward
// consistent flow f_t(p) whose end lands in the layer in frame t+1,
//     Σ ρ(|h_t(p) + s·w_t(p) − h_{t+1}(p + f) − s·w_{t+1}(p + f)|)
//       + λ Σ |∇w|² + μ Σ |w|²
// with h_t the frame → atlas homography (to_atlas [T,3,3]), s the atlas scale, ρ Charbonnier (a
// flow outlier pulls by at most its direction), λ the grid's smoothness and μ a small pull to
// zero that fixes the solution's free shift. `region(t)` [1,H,W] is the layer's share of frame t;
// flow [T−1,2,H,W] px and valid [T−1,1,H,W] as prepare writes them. Every `stride` px.
FlowWarpResult warps_from_flow(const torch::Tensor& to_atlas, double scale,
                               const torch::Tensor& flow, const torch::Tensor& valid,
                               const std::function<torch::Tensor(int64_t)>& region, int64_t gh,
                               int64_t gw, int iters = 400, int stride = 3);

struct ParallaxInit {
    torch::Tensor parallax;  // [1,1,gh,gw] γ over the atlas (grid_sample, align_corners false)
    torch::Tensor epipole;   // [T,3] refined
    // [T,3,3] each frame's correction of its homography in the atlas (the identity at frame 0;
    // undefined unless asked for): C_t(u) = u + b_t + M_t·(u − c)/R, c the atlas's centre
    torch::Tensor correction;
    double before_px = 0;  // mean disagreement of the flow's correspondences, γ = 0
    double after_px = 0;   // ... with γ and the epipoles
    // The same on the odd frame pairs (t → t+1, t odd) before and after a field fitted to the even
    // pairs alone: what the field predicts of pairs it was not fitted to. Scene depth is shared by
    // every pair; the flow's own errors are not. NaN with fewer than two pairs of each kind.
    double held_before_px = std::nan("");
    double held_after_px = std::nan("");
    int64_t points = 0;
    // The share of the odd pairs' disagreement the even pairs' field removes (NaN: not scored).
    double held_gain() const {
        return held_before_px > 0 ? 1 - held_after_px / held_before_px : std::nan("");
    }
};

// Plane + parallax (fast_model.h) started from the flow: γ and the epipoles minimising over the
// same correspondences as warps_from_flow
//     Σ ρ(|h_t(p) − h_{t+1}(p + f) − γ(u)·(d_{t+1}(u) − d_t(u))|) + λ Σ |∇γ|² + μ Σ γ²,
// u = h_t(p), d_t(u) = a_t + b_t·(u − c_t)/R, from `epipole` [T,3] (a_x, a_y, b) and `centre`
// [T,2] (atlas px). One γ for the clip: the correspondences of every pair constrain it. With four
// pairs or more γ is first fitted to the even pairs alone and scored on the odd ones
// (held_before_px / held_after_px), then fitted on from there to every pair, unless the odd
// pairs gained less than the share `min_held_gain` (> 0) or could not be scored: then γ stays
// zero and after_px is not computed (the caller keeps no field). With `correct_homographies` the
// fit to every pair also learns each frame's affine correction of its homography (frame 0 held;
// ParallaxInit::correction, fast.parallax_homography).
ParallaxInit parallax_from_flow(const torch::Tensor& to_atlas, const torch::Tensor& flow,
                                const torch::Tensor& valid,
                                const std::function<torch::Tensor(int64_t)>& region,
                                const torch::Tensor& epipole, const torch::Tensor& centre,
                                double radius, int64_t atlas_w, int64_t atlas_h, int64_t gh,
                                int64_t gw, double min_held_gain = 0, int iters = 150,
                                int stride = 4, bool correct_homographies = false);

}  // namespace refocus
