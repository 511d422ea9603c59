#include "radius/spectral_blur.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <cmath>

#include "util/error.h"

namespace refocus {

namespace {

std::vector<double> radius_grid(const SpectralBlurOptions& o) {
    std::vector<double> v;
    for (double r = o.rmin; r <= o.rmax + 1e-9; r += o.rstep) v.push_back(r);
    return v;
}

torch::Tensor tukey(int64_t n, double share) {
    auto w = torch::ones({n}, torch::kFloat64);
    const int64_t m = int64_t(share * n / 2);
    for (int64_t i = 0; i < m; ++i) {
        const double t = 0.5 * (1 - std::cos(M_PI * double(i) / double(m)));
        w[i] = t;
        w[n - 1 - i] = t;
    }
    return w;
}

// The pooling of a tile's frequencies into rings of |f| (0 < |f| < 1/2, width 1/max(h,w)).
struct Rings {
    torch::Tensor index;  // [h*w] ring of each frequency, −1 where not used
    torch::Tensor count;  // [G] frequencies per ring
    torch::Tensor freq;   // [G] mean |f| over the ring
    int64_t size = 0;
};

Rings make_rings(int64_t h, int64_t w) {
    auto fy = torch::fft::fftfreq(h, torch::kFloat64).view({h, 1});
    auto fx = torch::fft::fftfreq(w, torch::kFloat64).view({1, w});
    auto f = (fy * fy + fx * fx).sqrt().flatten();
    const double width = 1.0 / double(std::max(h, w));
    Rings r;
    const int64_t rings = int64_t(std::floor(0.5 / width));
    auto idx = (f / width).floor().to(torch::kLong).clamp_max(rings - 1);
    auto in = (f > 0) & (f < 0.5);
    // Only rings that hold a frequency (the first, under the lowest frequency, holds none),
    // renumbered in order.
    auto held = torch::zeros({rings}, torch::kLong).index_fill_(0, idx.masked_select(in), 1);
    auto renum = held.cumsum(0) - 1;
    r.size = held.sum().item<int64_t>();
    r.index = torch::where(in, renum.index({idx}), torch::full_like(idx, -1));
    auto used = r.index >= 0;
    auto ui = r.index.masked_select(used);
    r.count = torch::zeros({r.size}, torch::kFloat64)
                  .index_add_(0, ui, torch::ones({ui.size(0)}, torch::kFloat64));
    auto sum_f = torch::zeros({r.size}, torch::kFloat64).index_add_(0, ui, f.masked_select(used));
    r.freq = sum_f / r.count.clamp_min(1);
    return r;
}

// Ring medians of periodograms x [N, h*w] → [N, G], as means (÷ ln 2: the median of an
// exponential variable of mean v is v·ln 2). Stripes and checkers put lines on a ring, a few of
// its frequencies far above the rest, and a ring's mean follows them: a striped panel blurred
// 7.5-9 px reads as a small blur (docs/method.md, Radius estimation).
torch::Tensor pool_median(const torch::Tensor& x, const Rings& r) {
    std::vector<torch::Tensor> cols;
    for (int64_t g = 0; g < r.size; ++g) {
        auto idx = (r.index == g).nonzero().view({-1});
        cols.push_back(std::get<0>(x.index_select(1, idx).median(1)) / std::log(2.0));
    }
    return torch::stack(cols, 1);
}

// Ring means of x [N, h*w] → [N, G].
torch::Tensor pool(const torch::Tensor& x, const Rings& r) {
    auto used = r.index >= 0;
    auto ui = r.index.masked_select(used);
    auto xs = x.index({torch::indexing::Slice(), used});
    auto s = torch::zeros({x.size(0), r.size}, torch::kFloat64).index_add_(1, ui, xs);
    return s / r.count.clamp_min(1);
}

// |K_r(f)|² of the fit's kernel on the tile's frequency grid, pooled: [R, G]. The kernel is the
// lens blur layer's own (a delta blurred by it at constant radius), so the estimate is in the
// units the fit needs, whatever kernel it uses.
torch::Tensor kernel_power(const std::vector<double>& radii, int64_t h, int64_t w,
                           const LensBlurParams& kernel, const Rings& rings) {
    std::vector<torch::Tensor> rows;
    for (double r : radii) {
        const int64_t half = int64_t(std::ceil(lens_blur_support(r, kernel))) + 1;
        const int64_t s = 2 * half + 1;
        if (s > h || s > w)
            throw Error("spectral blur: a " + std::to_string(r) + " px kernel does not fit a " +
                        std::to_string(h) + "x" + std::to_string(w) + " tile");
        auto delta = torch::zeros({1, s, s}, torch::kFloat64);
        delta[0][half][half] = 1.0;
        auto k = lens_blur(delta, torch::full({s, s}, r, torch::kFloat64), kernel)[0];
        // Centred on (0, 0) of the tile, wrapped.
        auto padded = torch::zeros({h, w}, torch::kFloat64);
        padded.narrow(0, 0, s).narrow(1, 0, s).copy_(k);
        padded = torch::roll(padded, {-half, -half}, {0, 1});
        auto K = torch::fft::fft2(padded).abs().pow(2).flatten().unsqueeze(0);
        rows.push_back(pool(K, rings)[0]);
    }
    return torch::stack(rows);
}

// L(r) for tiles' pooled periodograms P [N, G] against A = |K|²/|f|² [R, G]: [N, R].
torch::Tensor evidence(const torch::Tensor& P, const torch::Tensor& A, const torch::Tensor& n,
                       int iters) {
    const int64_t N = P.size(0), R = A.size(0);
    auto Pn = P.view({N, 1, -1});
    auto An = A.view({1, R, -1});
    auto nn = n.view({1, 1, -1});
    // Start: c from the lowest quarter of rings (where |K|² ≈ 1), s² from the highest quarter.
    const int64_t G = P.size(1), q = std::max<int64_t>(1, G / 4);
    auto c0 =
        (P.narrow(1, 0, q) / A.select(0, 0).narrow(0, 0, q).view({1, -1})).mean(1).clamp_min(1e-30);
    auto s0 = (P.narrow(1, G - q, q).mean(1) * 0.5).clamp_min(1e-30);
    auto p = c0.log().view({N, 1}).expand({N, R}).clone();
    auto s = s0.log().view({N, 1}).expand({N, R}).clone();
    for (int it = 0; it < iters; ++it) {
        auto c = p.exp().unsqueeze(2), s2 = s.exp().unsqueeze(2);
        auto ca = c * An;
        auto v = ca + s2;
        auto res = nn * (v - Pn) / (v * v);  // ∂L/∂v
        auto gp = (res * ca).sum(2), gq = (res * s2).sum(2);
        auto ipp = (nn * (ca / v).pow(2)).sum(2), iqq = (nn * (s2 / v).pow(2)).sum(2);
        auto ipq = (nn * ca * s2 / (v * v)).sum(2);
        auto det = (ipp * iqq - ipq * ipq).clamp_min(1e-12);
        auto dp = -(iqq * gp - ipq * gq) / det, dq = -(ipp * gq - ipq * gp) / det;
        p = p + dp.clamp(-2, 2);
        s = s + dq.clamp(-2, 2);
    }
    auto v = p.exp().unsqueeze(2) * An + s.exp().unsqueeze(2);
    return (nn * (Pn / v + v.log())).sum(2);
}

torch::Tensor periodograms(const torch::Tensor& tiles, const SpectralBlurOptions& o) {
    // tiles [N, h, w] float64
    const int64_t h = tiles.size(1), w = tiles.size(2);
    auto win = torch::outer(tukey(h, o.taper), tukey(w, o.taper));
    auto x = (tiles - tiles.mean({1, 2}, true)) * win;
    return torch::fft::fft2(x).abs().pow(2).flatten(1) / win.pow(2).sum();
}

// L(r) [N, R], the least over the prior's exponents.
torch::Tensor evidence_over_exponents(const torch::Tensor& P, const torch::Tensor& K2,
                                      const Rings& rings, const SpectralBlurOptions& o) {
    torch::Tensor best;
    for (double a : o.exponents) {
        auto L = evidence(P, K2 * rings.freq.pow(-a).view({1, -1}), rings.count, o.fisher_iters);
        best = best.defined() ? torch::minimum(best, L) : L;
    }
    return best;
}

}  // namespace

torch::Tensor spectral_blur_evidence(const torch::Tensor& tile, const std::vector<double>& radii,
                                     const LensBlurParams& kernel, const SpectralBlurOptions& o) {
    const int64_t h = tile.size(0), w = tile.size(1);
    const Rings rings = make_rings(h, w);
    auto K2 = kernel_power(radii, h, w, kernel, rings);
    auto P = pool_median(periodograms(tile.to(torch::kFloat64).unsqueeze(0), o), rings);
    return evidence_over_exponents(P, K2, rings, o)[0];
}

SpectralBlurSamples measure_spectral_blur(const torch::Tensor& luma_in,
                                          const torch::Tensor& allowed_in,
                                          const LensBlurParams& kernel,
                                          const SpectralBlurOptions& o) {
    if (luma_in.dim() != 2) throw Error("spectral blur: luma must be [H,W]");
    // A frame wider than max_width is read at 1/k of its size (area average; a pixel allowed where
    // all its k×k are), and its readings scaled back by k: the tiles and radii above are sized
    // for frames of 320-480 px, where a blur this estimator is for spans 4.5-16 px.
    const int64_t k = std::max<int64_t>(1, (luma_in.size(1) + o.max_width - 1) / o.max_width);
    torch::Tensor luma = luma_in, allowed = allowed_in;
    if (k > 1) {
        namespace F = torch::nn::functional;
        auto pool = F::AvgPool2dFuncOptions(k).stride(k);
        luma = F::avg_pool2d(
            luma_in.to(torch::kFloat64).view({1, 1, luma_in.size(0), luma_in.size(1)}), pool)[0][0];
        allowed = F::avg_pool2d((allowed_in.to(torch::kFloat64) > 0.5)
                                    .to(torch::kFloat64)
                                    .view({1, 1, allowed_in.size(0), allowed_in.size(1)}),
                                pool)[0][0] > 0.999;
    }
    const int64_t H = luma.size(0), W = luma.size(1), th = o.tile_h, tw = o.tile_w;
    SpectralBlurSamples out;
    auto empty = torch::zeros({0}, torch::kFloat32);
    out.x = out.y = out.radius = empty;
    if (H < th || W < tw) return out;
    // A tile counts only where every pixel is allowed: the minimum over the tile, by integral
    // image.
    auto bad = (allowed.to(torch::kFloat64) < 0.5).to(torch::kFloat64);
    auto ii = torch::zeros({H + 1, W + 1}, torch::kFloat64);
    ii.narrow(0, 1, H).narrow(1, 1, W).copy_(bad.cumsum(0).cumsum(1));
    auto acc = ii.accessor<double, 2>();
    std::vector<int64_t> ys, xs;
    // At most max_tiles positions: the step grows past `stride` on large frames.
    int64_t stride = o.stride;
    while (((H - th) / stride + 1) * ((W - tw) / stride + 1) > o.max_tiles) stride += o.stride / 2;
    for (int64_t y0 = 0; y0 + th <= H; y0 += stride)
        for (int64_t x0 = 0; x0 + tw <= W; x0 += stride) {
            const double n =
                acc[y0 + th][x0 + tw] - acc[y0][x0 + tw] - acc[y0 + th][x0] + acc[y0][x0];
            if (n > 0.5) continue;
            ys.push_back(y0);
            xs.push_back(x0);
        }
    out.tiles = int64_t(ys.size());
    if (ys.empty()) return out;
    auto l = luma.to(torch::kFloat64);
    std::vector<torch::Tensor> tiles;
    tiles.reserve(ys.size());
    for (size_t i = 0; i < ys.size(); ++i)
        tiles.push_back(l.narrow(0, ys[i], th).narrow(1, xs[i], tw));
    const auto radii = radius_grid(o);
    const Rings rings = make_rings(th, tw);
    auto K2 = kernel_power(radii, th, tw, kernel, rings);
    auto P = pool_median(periodograms(torch::stack(tiles), o), rings);
    auto L = evidence_over_exponents(P, K2, rings, o);  // [N, R]
    auto best = L.argmin(1);
    auto La = L.accessor<double, 2>();
    auto ba = best.accessor<int64_t, 1>();
    const int64_t R = int64_t(radii.size());
    std::vector<float> rx, ry, rr;
    for (int64_t i = 0; i < L.size(0); ++i) {
        const int64_t b = ba[i];
        if (b == 0 || b == R - 1 || !std::isfinite(La[i][b]))
            continue;  // at an end of the range: no reading
        // Parabolic refinement through the neighbours.
        const double l0 = La[i][b - 1], l1 = La[i][b], l2 = La[i][b + 1];
        const double den = l0 - 2 * l1 + l2;
        const double off = den > 0 ? std::clamp(0.5 * (l0 - l2) / den, -0.5, 0.5) : 0.0;
        rr.push_back(float((radii[b] + off * o.rstep) * k));
        rx.push_back(float((xs[i] + 0.5 * tw) * k - 0.5 * (k - 1)));
        ry.push_back(float((ys[i] + 0.5 * th) * k - 0.5 * (k - 1)));
    }
    out.x = torch::tensor(rx, torch::kFloat32);
    out.y = torch::tensor(ry, torch::kFloat32);
    out.radius = torch::tensor(rr, torch::kFloat32);
    return out;
}

}  // namespace refocus
