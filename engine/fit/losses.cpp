#include "fit/losses.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>

namespace refocus {

namespace F = torch::nn::functional;

torch::Tensor srgb_encode(const torch::Tensor& x) {
    auto c = x.clamp(0.0, 1.0);
    auto hi = 1.055 * c.clamp_min(0.0031308).pow(1.0 / 2.4) - 0.055;
    return torch::where(c <= 0.0031308, c * 12.92, hi);
}

namespace {

torch::Tensor gauss_kernel(int64_t channels, const torch::TensorOptions& opts) {
    auto k = torch::arange(11, opts).sub(5.0).pow(2).div(-2.0 * 1.5 * 1.5).exp();
    k = k / k.sum();
    return k;
}

// Separable valid Gaussian filter, per channel, as 11 shifted multiply-adds per axis.
// (LibTorch 1.13's grouped conv2d takes a slow path on the CPU for this shape: ~100x slower.)
torch::Tensor gfilter(const torch::Tensor& x, const torch::Tensor& k1) {
    const int64_t w = x.size(3) - 10, h = x.size(2) - 10;
    auto k = k1.to(torch::kDouble);
    torch::Tensor y = x.narrow(3, 0, w) * k[0].item<double>();
    for (int64_t i = 1; i < 11; ++i) y = y + x.narrow(3, i, w) * k[i].item<double>();
    torch::Tensor z = y.narrow(2, 0, h) * k[0].item<double>();
    for (int64_t i = 1; i < 11; ++i) z = z + y.narrow(2, i, h) * k[i].item<double>();
    return z;
}

void ssim_terms(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& k,
                torch::Tensor* ssim, torch::Tensor* cs) {
    const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
    auto mu_a = gfilter(a, k), mu_b = gfilter(b, k);
    auto s_aa = gfilter(a * a, k) - mu_a * mu_a;
    auto s_bb = gfilter(b * b, k) - mu_b * mu_b;
    auto s_ab = gfilter(a * b, k) - mu_a * mu_b;
    auto cs_map = (2 * s_ab + c2) / (s_aa + s_bb + c2);
    auto l_map = (2 * mu_a * mu_b + c1) / (mu_a * mu_a + mu_b * mu_b + c1);
    *cs = cs_map.mean();
    *ssim = (l_map * cs_map).mean();
}

}  // namespace

torch::Tensor ms_ssim_loss(const torch::Tensor& a, const torch::Tensor& b) {
    static const double kWeights[5] = {0.0448, 0.2856, 0.3001, 0.2363, 0.1333};
    int64_t side = std::min(a.size(2), a.size(3));
    int scales = 5;
    while (scales > 1 && (side >> (scales - 1)) < 11) --scales;
    double wsum = 0;
    for (int i = 0; i < scales; ++i) wsum += kWeights[i];
    auto k = gauss_kernel(a.size(1), a.options());
    torch::Tensor x = a, y = b, prod = torch::ones({}, a.options());
    for (int s = 0; s < scales; ++s) {
        torch::Tensor ss, cs;
        ssim_terms(x, y, k, &ss, &cs);
        auto term = (s == scales - 1 ? ss : cs).clamp_min(1e-6);
        prod = prod * term.pow(kWeights[s] / wsum);
        if (s + 1 < scales) {
            x = F::avg_pool2d(x, F::AvgPool2dFuncOptions(2));
            y = F::avg_pool2d(y, F::AvgPool2dFuncOptions(2));
        }
    }
    return 1.0 - prod;
}

torch::Tensor tv_l1(const torch::Tensor& x) {
    const int64_t d = x.dim();
    auto dx = x.narrow(d - 1, 1, x.size(d - 1) - 1) - x.narrow(d - 1, 0, x.size(d - 1) - 1);
    auto dy = x.narrow(d - 2, 1, x.size(d - 2) - 1) - x.narrow(d - 2, 0, x.size(d - 2) - 1);
    return dx.abs().mean() + dy.abs().mean();
}

}  // namespace refocus
