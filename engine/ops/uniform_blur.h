#pragma once
// The lens blur layer (lens_blur.h) at a few uniform radii, by FFT: a direct blur costs about
// π·r² taps a pixel, this one the same two FFTs for every r. The focal-stack radius estimate
// (radius/stack_coc.h) blurs every frame's composite at each radius of its grid, which this
// makes cheap for large frames and large radii.
// Away from the border (the kernel's support R_s, lens_blur.h) it equals lens_blur with a
// uniform radius map, to float rounding. Within R_s of the border each output pixel is divided
// by the kernel's in-image sum there (a normalised convolution); lens_blur instead normalises
// each source's spread. Both keep a flat image flat.
#include <torch/types.h>

#include <cstdint>
#include <vector>

#include "ops/lens_blur.h"

namespace refocus {

class UniformBlurBank {
  public:
    // Frames of H x W, blurred at each of `radii` (px, ≥ 0) with `params`' kernel.
    UniformBlurBank(int64_t height, int64_t width, std::vector<double> radii,
                    const LensBlurParams& params);

    // An image [C,H,W]'s spectrum, computed once for all radii.
    torch::Tensor spectrum(const torch::Tensor& image) const;
    // The image of `spectrum` blurred at radii()[k]: [C,H,W].
    torch::Tensor blur(const torch::Tensor& spectrum, size_t k) const;

    const std::vector<double>& radii() const { return m_radii; }

  private:
    int64_t m_h = 0, m_w = 0, m_hp = 0, m_wp = 0;
    std::vector<double> m_radii;
    std::vector<torch::Tensor> m_kernel;    // [Hp, Wp/2+1] complex: the kernel's spectrum
    std::vector<torch::Tensor> m_inv_norm;  // [1,H,W]: 1 / the kernel's in-image sum
    std::vector<bool> m_identity;           // r ≤ min_radius: the image itself
};

}  // namespace refocus
