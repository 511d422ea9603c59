#include "fit/losses.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

torch::Tensor srgb_encode(const torch::Tensor& x) {
    auto c = x.clamp(0.0, 1.0);
    auto hi = 1.055 * c.clamp_min(0.0031308).pow(1.0 / 2.4) - 0.055;
    return torch::where(c <= 0.0031308, c * 12.92, hi);
}

namespace {

void check_planes(const torch::Tensor& x, const char* what) {
    if (!x.defined() || x.dim() != 4 || x.size(2) < 11 || x.size(3) < 11)
        throw Error(std::string(what) + ": needs [N,C,H,W] with H and W of at least 11 px");
}

constexpr int kTaps = 11;  // the Gaussian window of SSIM: 11 taps, σ 1.5

template <typename T>
std::array<T, kTaps> gauss_taps() {
    std::array<T, kTaps> k{};
    double s = 0;
    for (int i = 0; i < kTaps; ++i) s += std::exp(-(i - 5.0) * (i - 5.0) / (2 * 1.5 * 1.5));
    for (int i = 0; i < kTaps; ++i)
        k[i] = static_cast<T>(std::exp(-(i - 5.0) * (i - 5.0) / (2 * 1.5 * 1.5)) / s);
    return k;
}

// One plane, valid region: out[y][x] = Σ_ij k[i] k[j] in[y+i][x+j], rows then columns.
template <typename T>
void filter_plane(const T* in, T* out, T* tmp, int64_t h, int64_t w,
                  const std::array<T, kTaps>& k) {
    const int64_t wo = w - (kTaps - 1), ho = h - (kTaps - 1);
    for (int64_t y = 0; y < h; ++y) {
        const T* r = in + y * w;
        T* t = tmp + y * wo;
        for (int64_t x = 0; x < wo; ++x) t[x] = k[0] * r[x];
        for (int i = 1; i < kTaps; ++i)
            for (int64_t x = 0; x < wo; ++x) t[x] += k[i] * r[x + i];
    }
    for (int64_t y = 0; y < ho; ++y) {
        T* o = out + y * wo;
        for (int64_t x = 0; x < wo; ++x) o[x] = k[0] * tmp[y * wo + x];
        for (int i = 1; i < kTaps; ++i) {
            const T* t = tmp + (y + i) * wo;
            for (int64_t x = 0; x < wo; ++x) o[x] += k[i] * t[x];
        }
    }
}

// Its adjoint: spreads each output gradient back over the 11x11 window it read.
template <typename T>
void filter_plane_adjoint(const T* g, T* gin, T* tmp, int64_t h, int64_t w,
                          const std::array<T, kTaps>& k) {
    const int64_t wo = w - (kTaps - 1), ho = h - (kTaps - 1);
    std::fill(tmp, tmp + h * wo, T(0));
    for (int64_t y = 0; y < ho; ++y) {
        const T* gr = g + y * wo;
        for (int i = 0; i < kTaps; ++i) {
            T* t = tmp + (y + i) * wo;
            for (int64_t x = 0; x < wo; ++x) t[x] += k[i] * gr[x];
        }
    }
    for (int64_t y = 0; y < h; ++y) {
        T* o = gin + y * w;
        const T* t = tmp + y * wo;
        std::fill(o, o + w, T(0));
        for (int i = 0; i < kTaps; ++i)
            for (int64_t x = 0; x < wo; ++x) o[x + i] += k[i] * t[x];
    }
}

// Applies `fn(in_plane, out_plane, tmp)` to every [H,W] plane of a contiguous [N,C,H,W] tensor.
template <typename T, typename Fn>
void for_planes(const torch::Tensor& in, torch::Tensor& out, int64_t h, int64_t w, int64_t in_plane,
                int64_t out_plane, Fn fn) {
    const int64_t planes = in.size(0) * in.size(1);
    const T* src = in.data_ptr<T>();
    T* dst = out.data_ptr<T>();
    at::parallel_for(0, planes, 1, [&](int64_t b, int64_t e) {
        std::vector<T> tmp(h * (w - (kTaps - 1)));
        for (int64_t p = b; p < e; ++p) fn(src + p * in_plane, dst + p * out_plane, tmp.data());
    });
}

class GaussFilterFunction : public torch::autograd::Function<GaussFilterFunction> {
  public:
    static torch::Tensor forward(torch::autograd::AutogradContext*, const torch::Tensor& x) {
        auto in = x.contiguous();
        const int64_t h = in.size(2), w = in.size(3);
        auto out =
            torch::empty({in.size(0), in.size(1), h - (kTaps - 1), w - (kTaps - 1)}, in.options());
        const int64_t op = out.size(2) * out.size(3);
        AT_DISPATCH_FLOATING_TYPES(in.scalar_type(), "gauss_filter_valid", [&] {
            const auto k = gauss_taps<scalar_t>();
            for_planes<scalar_t>(in, out, h, w, h * w, op,
                                 [&](const scalar_t* i, scalar_t* o, scalar_t* t) {
                                     filter_plane(i, o, t, h, w, k);
                                 });
        });
        return out;
    }
    static torch::autograd::variable_list backward(torch::autograd::AutogradContext*,
                                                   torch::autograd::variable_list grads) {
        auto g = grads[0].contiguous();
        const int64_t h = g.size(2) + (kTaps - 1), w = g.size(3) + (kTaps - 1);
        auto gin = torch::empty({g.size(0), g.size(1), h, w}, g.options());
        const int64_t gp = g.size(2) * g.size(3);
        AT_DISPATCH_FLOATING_TYPES(g.scalar_type(), "gauss_filter_valid_adjoint", [&] {
            const auto k = gauss_taps<scalar_t>();
            for_planes<scalar_t>(g, gin, h, w, gp, h * w,
                                 [&](const scalar_t* i, scalar_t* o, scalar_t* t) {
                                     filter_plane_adjoint(i, o, t, h, w, k);
                                 });
        });
        return {gin};
    }
};

// The SSIM terms of one scale from the five filtered moments.
void ssim_maps(const torch::Tensor& mu_a, const torch::Tensor& mu_b, const torch::Tensor& f_aa,
               const torch::Tensor& f_bb, const torch::Tensor& f_ab, torch::Tensor* ssim,
               torch::Tensor* cs) {
    const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
    auto s_aa = f_aa - mu_a * mu_a;
    auto s_bb = f_bb - mu_b * mu_b;
    auto s_ab = f_ab - mu_a * mu_b;
    auto cs_map = (2 * s_ab + c2) / (s_aa + s_bb + c2);
    auto l_map = (2 * mu_a * mu_b + c1) / (mu_a * mu_a + mu_b * mu_b + c1);
    *cs = cs_map.mean();
    *ssim = (l_map * cs_map).mean();
}

void ssim_terms(const torch::Tensor& a, const torch::Tensor& b, bool reference, torch::Tensor* ssim,
                torch::Tensor* cs) {
    if (reference) {
        auto g = gauss_filter_valid_reference;
        ssim_maps(g(a), g(b), g(a * a), g(b * b), g(a * b), ssim, cs);
        return;
    }
    // Two filter calls instead of five: the moments that carry a gradient (of a, usually the
    // reblur) and those that do not (of b, the target), each stacked along the channels.
    auto fa = gauss_filter_valid(torch::cat({a, a * a, a * b}, 1)).chunk(3, 1);
    auto fb = gauss_filter_valid(torch::cat({b, b * b}, 1)).chunk(2, 1);
    ssim_maps(fa[0], fb[0], fa[1], fb[1], fa[2], ssim, cs);
}

torch::Tensor ms_ssim(const torch::Tensor& a, const torch::Tensor& b, bool reference) {
    static const double kWeights[5] = {0.0448, 0.2856, 0.3001, 0.2363, 0.1333};
    int64_t side = std::min(a.size(2), a.size(3));
    int scales = 5;
    while (scales > 1 && (side >> (scales - 1)) < kTaps) --scales;
    double wsum = 0;
    for (int i = 0; i < scales; ++i) wsum += kWeights[i];
    torch::Tensor x = a, y = b, prod = torch::ones({}, a.options());
    for (int s = 0; s < scales; ++s) {
        torch::Tensor ss, cs;
        ssim_terms(x, y, reference, &ss, &cs);
        auto term = (s == scales - 1 ? ss : cs).clamp_min(1e-6);
        prod = prod * term.pow(kWeights[s] / wsum);
        if (s + 1 < scales) {
            x = F::avg_pool2d(x, F::AvgPool2dFuncOptions(2));
            y = F::avg_pool2d(y, F::AvgPool2dFuncOptions(2));
        }
    }
    return 1.0 - prod;
}

}  // namespace

torch::Tensor ms_ssim_loss(const torch::Tensor& a, const torch::Tensor& b) {
    return ms_ssim(a, b, false);
}

torch::Tensor ms_ssim_loss_reference(const torch::Tensor& a, const torch::Tensor& b) {
    return ms_ssim(a, b, true);
}

torch::Tensor gauss_filter_valid(const torch::Tensor& x) {
    check_planes(x, "gauss_filter_valid");
    return GaussFilterFunction::apply(x);
}

torch::Tensor gauss_filter_valid_reference(const torch::Tensor& x) {
    check_planes(x, "gauss_filter_valid_reference");
    const auto k = gauss_taps<double>();
    const int64_t w = x.size(3) - (kTaps - 1), h = x.size(2) - (kTaps - 1);
    torch::Tensor y = x.narrow(3, 0, w) * k[0];
    for (int i = 1; i < kTaps; ++i) y = y + x.narrow(3, i, w) * k[i];
    torch::Tensor z = y.narrow(2, 0, h) * k[0];
    for (int i = 1; i < kTaps; ++i) z = z + y.narrow(2, i, h) * k[i];
    return z;
}

torch::Tensor tv_l1(const torch::Tensor& x, const torch::Tensor& weight) {
    const int64_t d = x.dim();
    auto diff = [&](const torch::Tensor& t, int64_t dim) {
        return t.narrow(dim, 1, t.size(dim) - 1) - t.narrow(dim, 0, t.size(dim) - 1);
    };
    auto pair_mean = [&](const torch::Tensor& t, int64_t dim) {
        return 0.5 * (t.narrow(dim, 1, t.size(dim) - 1) + t.narrow(dim, 0, t.size(dim) - 1));
    };
    auto dx = diff(x, d - 1).abs(), dy = diff(x, d - 2).abs();
    if (!weight.defined()) return dx.mean() + dy.mean();
    return (dx * pair_mean(weight, d - 1)).mean() + (dy * pair_mean(weight, d - 2)).mean();
}

torch::Tensor tv_radius_factor(const torch::Tensor& r_sharp, const torch::Tensor& r_mean,
                               const torch::Tensor& r_sq_mean, double gain, double cap,
                               double spread, double fade) {
    auto sd = (r_sq_mean - r_mean * r_mean).clamp_min(0).sqrt();
    auto same = (1.0 - sd / std::max(spread, 1e-6)).clamp(0, 1);
    if (fade > 0) same = same * (fade - r_sharp).clamp(0, 1);
    return 1.0 + ((gain * r_sharp).clamp(1.0, std::max(cap, 1.0)) - 1.0) * same;
}

}  // namespace refocus
