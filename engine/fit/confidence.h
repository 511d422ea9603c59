#pragma once
// Never worse than the shot (docs/method.md, Confidence and fallback). The output of frame t is
//     S_t = w_t · C_t + (1 − w_t) · I_t,      w_t = κ_t · ν_t
// with C_t the model's sharp frame, I_t the input, κ_t the confidence that the model explains
// the region (agreement of the frames that see it through the shared atlas) and ν_t the need: 0
// where no blur reaches the pixel (nothing to fix, the shot is already the answer).
#include <torch/types.h>

#include <functional>

namespace refocus {

// How much of frame t's residual the model leaves unexplained, [1,1,H,W] in [0,1], from its
// running reblur residual `resid` ([1,1,H,W], sRGB, -1 where not measured yet: undefined
// returned): smoothstep from max(k·median, min) to twice that, opened by 9 px (a thin band along
// an occlusion edge is better fitted than the shot), grown and feathered by 4 px (no seam).
torch::Tensor unexplained_share(const torch::Tensor& resid, double k, double min);

// Map m_s ([1,C,H,W]) of frame s drawn in frame t's pixels through the camera's homographies
// (to_ref [T,3,3] float64, frame → reference; border padding).
torch::Tensor warp_frame_map(const torch::Tensor& m_s, const torch::Tensor& to_ref, int s, int t);

// The unexplained share of frame t made smooth in time: the larger of its own and the mean of
// frames t ± window drawn in frame t (through the homographies): a frame keeps its own fallback,
// and a region that falls back around it fades in and out. `u_of(s)` gives frame s's share
// (undefined: not measured, left out). Undefined when frame t's own share is undefined.
torch::Tensor temporal_unexplained(int t, int frames, int window, const torch::Tensor& to_ref,
                                   bool static_camera,
                                   const std::function<torch::Tensor(int)>& u_of);

// ν: 0 where no blur of radius ≥ focus_px reaches the pixel, 1 from twice that. The blur of a
// pixel q reaches p when |p − q| ≤ r(q): r is dilated by a cone (iterated 3x3 max − 1 px), so a
// blurred subject's spill over an in-focus wall counts as blur to fix. radius [H,W] px.
torch::Tensor blur_need(const torch::Tensor& radius, double focus_px);

}  // namespace refocus
