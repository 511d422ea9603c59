#pragma once
// Never worse than the shot (docs/method.md, Confidence and fallback). The output of frame t is
//     S_t = w_t · C_t + (1 − w_t) · I_t,      w_t = κ_t · τ_t · ν_t · γ_t
// with C_t the model's sharp frame, I_t the input, κ_t the confidence that the model explains
// the region (agreement of the frames that see it through the shared atlas), τ_t the trust that
// some frame recorded its detail, ν_t the need (0 where no blur reaches the pixel: nothing to
// fix, the shot is already the answer) and γ_t whether another frame saw it sharper.
#include <torch/types.h>

#include <functional>

namespace refocus {

// How much of frame t's residual the model leaves unexplained, [1,1,H,W] in [0,1], from its
// running reblur residual `resid` ([1,1,H,W], sRGB, -1 where not measured yet: undefined
// returned): smoothstep from max(k·median, min) to twice that, grown and feathered by 4 px (no
// seam). Thin unexplained bands are kept: under parallax they are where the atlas is wrong.
torch::Tensor unexplained_share(const torch::Tensor& resid, double k, double min);

// Map m_s ([1,C,H,W]) of frame s drawn in frame t's pixels through the camera's homographies
// (to_ref [T,3,3] float64, frame → reference; border padding, or zeros with outside_zero).
torch::Tensor warp_frame_map(const torch::Tensor& m_s, const torch::Tensor& to_ref, int s, int t,
                             bool outside_zero = false);

// κ's evidence rule: the unexplained share where the running residual `resid` ([1,1,H,W] sRGB,
// as unexplained_share reads it) passes what a right model leaves there, the noise plus a share
// of what the model changes over its own reblur: lo = 0.8·σ/255 + change_share·change + floor
// (`change` = |C − Î|, the same units; 0.8σ is the mean |noise| of a channel), smoothstep from
// lo to 2·lo, grown and feathered by 4 px. A model that restores much may miss the input by
// more than one that restores little; a residual past both is a wrong model, not noise.
torch::Tensor unexplained_share_evidence(const torch::Tensor& resid, const torch::Tensor& change,
                                         double noise_levels, double change_share, double floor);

// The unexplained share of frame t made smooth in time: the larger of its own and the mean of
// frames t ± window drawn in frame t (through the homographies): a frame keeps its own fallback,
// and a region that falls back around it fades in and out. `u_of(s)` gives frame s's share
// (undefined: not measured, left out). Undefined when frame t's own share is undefined.
torch::Tensor temporal_unexplained(int t, int frames, int window, const torch::Tensor& to_ref,
                                   bool static_camera,
                                   const std::function<torch::Tensor(int)>& u_of);

// The sharpest the clip saw each pixel of frame t: the least radius over frames s (t, and at
// most `max_frames` others spread over the clip) of frame s's radius map drawn into frame t
// through the homographies ([1,1,H,W] px). A pixel frame s did not see takes `unseen_px` from
// it. `radius_of(s)` gives frame s's map ([H,W] px).
torch::Tensor sharpest_seen(int t, int frames, int max_frames, const torch::Tensor& to_ref,
                            bool static_camera, double unseen_px,
                            const std::function<torch::Tensor(int)>& radius_of);

// The least and the largest radius with which the clip saw each pixel of frame t ([1,1,H,W] px
// each), over the same frames as sharpest_seen. A frame that did not see the pixel counts for
// neither. `most − least` is how far focus moved over the point; `most` is left undefined
// unless with_most.
struct SeenRadius {
    torch::Tensor least, most;
};
SeenRadius seen_radius(int t, int frames, int max_frames, const torch::Tensor& to_ref,
                       bool static_camera, double unseen_px,
                       const std::function<torch::Tensor(int)>& radius_of, bool with_most = true);

// What of a reblur residual's RMS (8-bit levels, FitEngine::residual_rms) the noise of σ levels
// does not leave: √max(0, rms² − (0.8σ)²), 0.8σ the mean |noise| of a channel.
double residual_excess(double rms, double noise_levels);

// How far a fit whose reblur misses the clip by `rms` explains it: 1 where residual_excess is
// under `lo`, 0 from 1.4·lo (smoothstep). 0 where rms is not finite (never measured) or lo ≤ 0.
double explained_trust(double rms, double noise_levels, double lo);

// τ: how far the model is trusted to restore a pixel that the sharpest frame saw blurred by
// `sharpest` px: 1 up to trust_px, 0 from twice that (smoothstep), feathered by 4 px. Detail
// that no frame recorded comes from deconvolution alone, which noise and a kernel that differs
// from the lens turn into ringing (docs/method.md, Confidence and fallback).
torch::Tensor seen_trust(const torch::Tensor& sharpest, double trust_px);

// How far blur reaches each pixel: the cone dilation max_q (r(q) − |p − q|) of radius [H,W] px
// (iterated 3x3 max − 1 px), so that a blurred subject's spill over an in-focus wall counts.
// [1,1,H,W] px; ν and γ read it.
torch::Tensor blur_reach(const torch::Tensor& radius);
// The same by LibTorch's max pooling, one allocation a step: the reference blur_reach's fused
// loop is tested against (equal to the last bit).
torch::Tensor blur_reach_reference(const torch::Tensor& radius);

// ν: 0 where no blur of radius ≥ focus_px reaches the pixel, 1 from twice that. reach: blur_reach.
torch::Tensor blur_need(const torch::Tensor& reach, double focus_px);

// γ: 0 where frame t is (within gain_px) its own sharpest view of the pixel, 1 where some frame
// saw it sharper by twice that: the reach of frame t's blur (blur_reach of its radius, so that a
// blurred subject's spill counts) less `sharpest` (sharpest_seen), smoothstep from gain_px to
// 2·gain_px, feathered by 4 px. The atlas carries detail over from a sharper view; where there
// is none, what it adds is deconvolution's. reach and sharpest [1,1,H,W] px.
torch::Tensor sharper_view(const torch::Tensor& reach, const torch::Tensor& sharpest,
                           double gain_px);

// γ with a threshold that depends on how far focus moved over the point (`range`, most − least
// of seen_radius): gain_px where it never moved by more than 0.6·moved_px, moved_gain_px from
// moved_px on (smoothstep between). Where focus passed over a point the clip holds a measured
// sharp view of it and its radius was read against that view, so a small sharper view is real;
// where focus never moved, a radius that differs by a few px between frames is the estimate's
// noise.
torch::Tensor sharper_view(const torch::Tensor& reach, const torch::Tensor& sharpest,
                           const torch::Tensor& range, double gain_px, double moved_gain_px,
                           double moved_px);

// How far a layer's focus moved over the clip as a whole: the range over frames of the median
// radius of `radius_of(s)` ([H,W] px) over the pixels `region_of(s)` ([H,W], ≥ 0.5) holds
// (every pixel when undefined); frames where the region covers under 1 % of the frame are left
// out. A pixel's own range is the estimate's noise too; a layer's median over a whole frame is not.
// Frames over ~65 000 px are read on a grid (a median needs no more).
double focus_travel(int frames, const std::function<torch::Tensor(int)>& radius_of,
                    const std::function<torch::Tensor(int)>& region_of);

// The least and the most of those per-frame medians (focus_travel is their difference); `seen`
// is false when no frame's region reached 1 %.
struct FocusSpan {
    double least = 0, most = 0;
    bool seen = false;
};
FocusSpan focus_span(int frames, const std::function<torch::Tensor(int)>& radius_of,
                     const std::function<torch::Tensor(int)>& region_of);

// The focus range (most − least of seen_radius, [1,1,H,W] px) rescaled for the sharper-view rule
// where the layer's focus travelled (focus_travel): from `travel_px` on, a point passed over by
// half the layer's travel counts as moved (sharper_view's moved_px), however small the travel;
// under 0.75·travel_px the range is left as it is (smoothstep between). 0 travel_px: unchanged.
torch::Tensor range_by_travel(const torch::Tensor& range, double travel, double moved_px,
                              double travel_px);

// Separable Gaussian of standard deviation sigma px (support ±3σ, edges replicated), [N,C,H,W].
torch::Tensor gaussian_blur(const torch::Tensor& x, double sigma);

// The low-frequency lock: the correction G_σ(I) − G_σ(C) that gives the model's frame C
// ([N,C,H,W]) the input I's content below scale σ. A lens blur keeps local means, so the
// difference there is the model's error (a colour shift, a misregistered edge), never detail
// the blur removed. Added to every layer, α·F + (1 − α)·B takes it as the plate does.
torch::Tensor low_frequency_lock(const torch::Tensor& model, const torch::Tensor& input,
                                 double sigma);

}  // namespace refocus
