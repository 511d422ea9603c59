#pragma once
// Reconstruction losses of paper §3.5: L1 + MS-SSIM between the reblurred and the input frames
// (Zhao et al. 2016), on sRGB-encoded values so that errors weigh as they are seen and measured.
#include <torch/types.h>

namespace refocus {

// IEC 61966-2-1 encode, differentiable (the linear toe keeps the gradient finite at 0).
torch::Tensor srgb_encode(const torch::Tensor& linear);

// Mean SSIM and contrast-structure terms of [N,C,H,W] images in [0,1] (11x11 Gaussian, σ 1.5,
// valid region), as in engine/metrics but differentiable.
torch::Tensor ms_ssim_loss(const torch::Tensor& a, const torch::Tensor& b);  // 1 − MS-SSIM

// Anisotropic total variation: mean |∂x| + |∂y| of [..., H, W].
torch::Tensor tv_l1(const torch::Tensor& x);

}  // namespace refocus
