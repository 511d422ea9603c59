#pragma once
// Reconstruction losses of paper §3.5: L1 + MS-SSIM between the reblurred and the input frames
// (Zhao et al. 2016), on sRGB-encoded values so that errors weigh as they are seen and measured.
#include <torch/types.h>

namespace refocus {

// IEC 61966-2-1 encode, differentiable (the linear toe keeps the gradient finite at 0).
torch::Tensor srgb_encode(const torch::Tensor& linear);

// Mean SSIM and contrast-structure terms of [N,C,H,W] images in [0,1] (11x11 Gaussian, σ 1.5,
// valid region), as in engine/metrics but differentiable.
// The fast path filters with a fused loop (forward and adjoint) and stacks the moments, several
// times faster than the reference (docs/benchmarks.md, Speed), which builds the filter from 22
// shifted tensor multiply-adds per moment. Tests hold the two to each other.
torch::Tensor ms_ssim_loss(const torch::Tensor& a, const torch::Tensor& b);  // 1 − MS-SSIM
torch::Tensor ms_ssim_loss_reference(const torch::Tensor& a, const torch::Tensor& b);

// The SSIM window over each [H,W] plane of [N,C,H,W] (valid region: [N,C,H-10,W-10]),
// differentiable; the reference is the same filter in tensor ops.
torch::Tensor gauss_filter_valid(const torch::Tensor& x);
torch::Tensor gauss_filter_valid_reference(const torch::Tensor& x);

// Anisotropic total variation: mean |∂x| + |∂y| of [..., H, W]; with `weight` ([..., H, W],
// broadcast over the channels) each difference is weighed by its two pixels' mean weight.
torch::Tensor tv_l1(const torch::Tensor& x, const torch::Tensor& weight = {});

// How much more TV a texel needs, from the blur radii (px) its views saw it at: `r_sharp` the
// radius of its sharpest views, `r_mean` and `r_sq_mean` the mean radius and mean squared radius
// over all its views. A texel seen at one radius r in every view (a fixed focus: synth pan's
// wall, whose radius depends on the row only) has lost what lies past the disk's first spectral
// zero (~0.61 / r cycles per px) in all of them, and there TV has to fill in more; a texel seen
// at several radii has those frequencies from the others (a focus change moves the zeros). So:
// clamp(gain · r_sharp, 1, cap) where the radii vary (standard deviation) by 0, blending to 1 at
// `spread` px and beyond. With `fade` > 0 it also blends to 1 as r_sharp goes from fade − 1 to
// fade px. More TV helps a layer blurred a few px in every view (synth pan's wall and subject)
// but flattens a glyph wall blurred 5–9 px (synth walkout's), so the fast model fades the
// background atlas's weight from 4 to 5 px and keeps the subject's at any radius
// (docs/method.md, Model).
torch::Tensor tv_radius_factor(const torch::Tensor& r_sharp, const torch::Tensor& r_mean,
                               const torch::Tensor& r_sq_mean, double gain, double cap,
                               double spread, double fade = 0);

}  // namespace refocus
