#include "ops/uniform_blur.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>

#include "util/error.h"

namespace refocus {

namespace {

// The least n' ≥ n whose prime factors are 2, 3 and 5: FFT lengths that pocketfft does fastest.
int64_t smooth_length(int64_t n) {
    for (int64_t m = std::max<int64_t>(n, 1);; ++m) {
        int64_t r = m;
        for (int64_t p : {2, 3, 5})
            while (r % p == 0) r /= p;
        if (r == 1) return m;
    }
}

}  // namespace

UniformBlurBank::UniformBlurBank(int64_t height, int64_t width, std::vector<double> radii,
                                 const LensBlurParams& params)
    : m_h(height), m_w(width), m_radii(std::move(radii)) {
    if (height < 1 || width < 1) throw Error("uniform blur: empty frame size");
    check_lens_blur_params(params);
    double rmax = 0;
    for (double r : m_radii) {
        if (!(r >= 0) || !std::isfinite(r)) throw Error("uniform blur: a radius is not >= 0");
        rmax = std::max(rmax, r);
    }
    // Linear (not circular) convolution: the frame is zero-padded by the kernel's reach.
    const int64_t P = int64_t(std::ceil(lens_blur_support(rmax, params))) + 1;
    // ... and holds the whole kernel (2P + 1 taps), which a frame thinner than P does not.
    m_hp = smooth_length(std::max(height + P, 2 * P + 1));
    m_wp = smooth_length(std::max(width + P, 2 * P + 1));
    torch::NoGradGuard no_grad;
    const std::vector<int64_t> size{m_hp, m_wp};
    const auto ones = torch::fft::rfft2(torch::ones({1, height, width}), size);
    for (double r : m_radii) {
        m_identity.push_back(r <= params.min_radius);
        if (m_identity.back()) {
            m_kernel.emplace_back();
            m_inv_norm.emplace_back();
            continue;
        }
        // The kernel as lens_blur spreads one source pixel far from the border (its taps,
        // blend with the identity and normalisation included), centred on (0, 0) circularly.
        auto delta = torch::zeros({1, 2 * P + 1, 2 * P + 1});
        delta[0][P][P] = 1.0f;
        const auto k = lens_blur(delta, torch::full({2 * P + 1, 2 * P + 1}, float(r)), params);
        auto full = torch::zeros({1, m_hp, m_wp});
        full.narrow(1, 0, 2 * P + 1).narrow(2, 0, 2 * P + 1).copy_(k);
        const auto spec = torch::fft::rfft2(torch::roll(full, {-P, -P}, {1, 2}));
        const auto norm =
            torch::fft::irfft2(ones * spec, size).narrow(1, 0, height).narrow(2, 0, width);
        m_kernel.push_back(spec[0]);
        m_inv_norm.push_back(1.0 / norm.clamp_min(1e-6));
    }
}

torch::Tensor UniformBlurBank::spectrum(const torch::Tensor& image) const {
    if (image.dim() != 3 || image.size(1) != m_h || image.size(2) != m_w)
        throw Error("uniform blur: the image is not [C," + std::to_string(m_h) + "," +
                    std::to_string(m_w) + "]");
    return torch::fft::rfft2(image.to(torch::kFloat32), std::vector<int64_t>{m_hp, m_wp});
}

torch::Tensor UniformBlurBank::blur(const torch::Tensor& spectrum, size_t k) const {
    if (k >= m_radii.size()) throw Error("uniform blur: no such radius");
    if (m_identity[k])
        return torch::fft::irfft2(spectrum, std::vector<int64_t>{m_hp, m_wp})
            .narrow(1, 0, m_h)
            .narrow(2, 0, m_w);
    return torch::fft::irfft2(spectrum * m_kernel[k], std::vector<int64_t>{m_hp, m_wp})
               .narrow(1, 0, m_h)
               .narrow(2, 0, m_w) *
           m_inv_norm[k];
}

}  // namespace refocus
