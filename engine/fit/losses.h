#pragma once
// Reconstruction losses of paper §3.5: L1 + MS-SSIM between the reblurred and the input frames
// (Zhao et al. 2016), on sRGB-encoded values so that errors weigh as they are seen and measured.
#include <torch/types.h>

namespace refocus {

// IEC 61966-2-1 encode, differentiable (the linear toe keeps the gradient finite at 0).
torch::Tensor srgb_encode(const torch::Tensor& linear);

// Mean SSIM and contrast-structure terms of [N,C,H,W] images in [0,1] (11x11 Gaussian, σ 1.5,
// valid region), as in engine/metrics but differentiable.
// The fast path filters with a fused loop (forward and adjoint) and stacks the moments: on a
// 2x3x180x320 batch, forward and backward take ~4x less time than the reference, which builds the
// filter from 22 shifted tensor multiply-adds per moment. Tests hold the two to each other.
torch::Tensor ms_ssim_loss(const torch::Tensor& a, const torch::Tensor& b);  // 1 − MS-SSIM
torch::Tensor ms_ssim_loss_reference(const torch::Tensor& a, const torch::Tensor& b);

// The SSIM window over each [H,W] plane of [N,C,H,W] (valid region: [N,C,H-10,W-10]),
// differentiable; the reference is the same filter in tensor ops.
torch::Tensor gauss_filter_valid(const torch::Tensor& x);
torch::Tensor gauss_filter_valid_reference(const torch::Tensor& x);

// Anisotropic total variation: mean |∂x| + |∂y| of [..., H, W].
torch::Tensor tv_l1(const torch::Tensor& x);

}  // namespace refocus
