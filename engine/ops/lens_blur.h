#pragma once
// The lens blur layer (paper §3.3, eq. 2 and 3): a per-pixel scatter-sum where every source
// pixel spreads its colour over its own disk of radius r (px), with its kernel normalised to
// unit sum. Differentiable in the image and in the radius. See lens_blur.cpp.
#include <torch/types.h>

namespace refocus {

enum class BlurKernel {
    Disk,      // paper eq. 2: k = e^{βd} / (e^{βd} − d), d = r − sqrt(x²+y²)
    Pillbox,   // seed 001 eq. 1.13: 1/(πr²) inside the circle, 0 outside
    Gaussian,  // seed 001 eq. 1.20: σ = κ·r
};

struct LensBlurParams {
    BlurKernel kernel = BlurKernel::Disk;
    double beta = 2.0;          // disk fall-off; must be > 1/e
    double kappa = 1.2;         // Gaussian σ = κ·r
    double min_radius = 0.25;   // below this a pixel costs one tap (identity)
};

// image [C,H,W] (float or double, linear light), radius [H,W] ≥ 0 in px → [C,H,W].
torch::Tensor lens_blur(const torch::Tensor& image, const torch::Tensor& radius,
                        const LensBlurParams& params = {});

// The adjoint (gather) H* of the blur with a fixed radius map: <H x, y> = <x, H* y>.
torch::Tensor lens_blur_adjoint(const torch::Tensor& grad_out, const torch::Tensor& radius,
                                const LensBlurParams& params = {});

}  // namespace refocus
