#pragma once
// Residual warps that follow parallax (docs/method.md, Model: parallax within a layer). A layer of
// a 3D scene seen from a moving camera is not carried from frame to frame by one homography: a
// pillar in front of a wall slides across it. The optical flow between neighbouring frames sees
// that slide; these warps make a layer's atlas coordinates agree with it before the fit starts,
// which a warp learned from zero at a fraction of a pixel a step would take hundreds of steps to
// reach.
#include <torch/types.h>

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

}  // namespace refocus
