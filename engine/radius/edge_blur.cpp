#include "radius/edge_blur.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <cmath>
#include <map>
#include <mutex>

#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

std::vector<double> grid(double lo, double hi, double step) {
    std::vector<double> v;
    for (double x = lo; x <= hi + 1e-9; x += step) v.push_back(x);
    return v;
}

// Bilinear samples of img [1,1,H,W] at pixel coordinates xs, ys (any equal shapes); `fill` 0
// outside the image (zeros padding) for validity maps, otherwise the border value.
torch::Tensor sample(const torch::Tensor& img, const torch::Tensor& xs, const torch::Tensor& ys,
                     bool zeros) {
    const int64_t H = img.size(2), W = img.size(3);
    auto gx = xs * (2.0 / std::max<int64_t>(W - 1, 1)) - 1.0,
         gy = ys * (2.0 / std::max<int64_t>(H - 1, 1)) - 1.0;
    auto g = torch::stack({gx, gy}, -1).to(torch::kFloat32).reshape({1, -1, 1, 2});
    auto v = torch::grid_sampler(img, g, 0, zeros ? 0 : 1, true);  // bilinear, align_corners
    return v.reshape(xs.sizes());
}

}  // namespace

torch::Tensor edge_spread_table(const LensBlurParams& kernel, const EdgeBlurOptions& o,
                                std::vector<double>* radii_out, std::vector<double>* offsets_out) {
    const auto radii = grid(0.0, o.rmax, o.rstep), offsets = grid(-1.0, 1.0, 0.25);
    if (radii_out) *radii_out = radii;
    if (offsets_out) *offsets_out = offsets;
    // The table costs ~10⁹ taps (49 radii up to 12 px) and depends only on the kernel and the
    // grid: it is made once per process, not once per frame and layer.
    static std::mutex mutex;
    static std::map<std::vector<double>, torch::Tensor> cache;
    const std::vector<double> key = {
        double(kernel.kernel), kernel.beta, kernel.kappa, kernel.min_radius,
        double(o.reach),       o.rmax,      o.rstep};
    {
        std::lock_guard<std::mutex> lock(mutex);
        auto it = cache.find(key);
        if (it != cache.end()) return it->second;
    }
    // The lens blur layer normalises each source pixel's kernel over its in-image taps, so a
    // source within r of the image border deposits more into the taps it keeps: the rows and
    // columns read must be more than 2r from every border (nearer, the step's far side reads
    // too high).
    const int64_t S = 2 * o.reach + 1, margin = 2 * int64_t(std::ceil(o.rmax)) + 3;
    const int64_t Ww = S + 2 * margin, Hh = 2 * margin + 1;
    // A vertical step at x = s0 (pixel x covers [x − ½, x + ½]: its value is the share of it
    // right of s0), one channel per offset, blurred by the kernel at each radius; the middle
    // row, across the step, is the step response the model fits.
    auto xs = torch::arange(Ww, torch::kFloat64) - double(o.reach + margin);
    std::vector<torch::Tensor> steps;
    for (double s0 : offsets) steps.push_back((xs + 0.5 - s0).clamp(0, 1));
    auto img = torch::stack(steps)
                   .view({int64_t(offsets.size()), 1, Ww})
                   .expand({-1, Hh, -1})
                   .to(torch::kFloat32)
                   .contiguous();
    std::vector<torch::Tensor> rows;
    for (double r : radii) {
        auto b = lens_blur(img, torch::full({Hh, Ww}, float(r)), kernel);
        rows.push_back(b.select(1, Hh / 2).narrow(1, margin, S).to(torch::kFloat64));
    }
    auto table = torch::cat(rows, 0).contiguous();  // [R·O, S]
    std::lock_guard<std::mutex> lock(mutex);
    return cache.emplace(key, table).first->second;
}

EdgeBlurSamples measure_edge_blur(const torch::Tensor& luma_in, const torch::Tensor& allowed_in,
                                  const LensBlurParams& kernel, const EdgeBlurOptions& o) {
    torch::NoGradGuard no_grad;
    if (luma_in.dim() != 2 || allowed_in.sizes() != luma_in.sizes())
        throw Error("measure_edge_blur: luma and allowed must be [H,W] of one size");
    EdgeBlurSamples out;
    const int64_t H = luma_in.size(0), W = luma_in.size(1);
    auto L = luma_in.to(torch::kFloat32).contiguous().view({1, 1, H, W});
    auto allowed = allowed_in.to(torch::kFloat32).contiguous().view({1, 1, H, W});
    auto empty = [&] {
        out.x = out.y = out.radius = out.residual = torch::empty({0}, torch::kFloat32);
        return out;
    };
    const int64_t gr = int64_t(std::ceil(3 * o.sigma));
    if (H < 2 * gr + 3 || W < 2 * gr + 3) return empty();

    // 1. Gradient (Gaussian derivative, σ) and its maxima along its own direction (Canny's
    //    non-maximum suppression), above a quantile of the allowed pixels' gradients.
    auto i = torch::arange(-gr, gr + 1, torch::kFloat32);
    auto g = torch::exp(-i * i / float(2 * o.sigma * o.sigma));
    g = g / g.sum();
    auto dg = i * g / float(o.sigma * o.sigma);  // correlation with this ≈ the derivative
    auto Lp = F::pad(L, F::PadFuncOptions({gr, gr, gr, gr}).mode(torch::kReplicate));
    auto gx = F::conv2d(F::conv2d(Lp, dg.view({1, 1, 1, -1})), g.view({1, 1, -1, 1}))[0][0];
    auto gy = F::conv2d(F::conv2d(Lp, g.view({1, 1, 1, -1})), dg.view({1, 1, -1, 1}))[0][0];
    auto mag = torch::sqrt(gx * gx + gy * gy);
    auto nx = gx / mag.clamp_min(1e-12), ny = gy / mag.clamp_min(1e-12);
    auto yy = torch::arange(H, torch::kFloat32).view({H, 1}).expand({H, W});
    auto xx = torch::arange(W, torch::kFloat32).view({1, W}).expand({H, W});
    auto magi = mag.view({1, 1, H, W});
    auto m1 = sample(magi, xx + nx, yy + ny, false), m2 = sample(magi, xx - nx, yy - ny, false);
    auto inside = allowed[0][0] > 0.5;
    if (inside.sum().item<int64_t>() == 0) return empty();
    auto mags = mag.masked_select(inside);
    const int64_t kq =
        std::clamp<int64_t>(int64_t(o.edge_quantile * mags.numel()), 1, mags.numel());
    const double thr = std::max(1e-6, std::get<0>(mags.kthvalue(kq)).item<double>());
    auto cand = (mag >= m1) & (mag >= m2) & (mag > thr) & inside;
    auto idx = torch::nonzero(cand);  // [N,2] (y, x), row-major order
    if (idx.size(0) > o.max_candidates) {
        const int64_t stride = (idx.size(0) + o.max_candidates - 1) / o.max_candidates;
        idx = idx.index({torch::indexing::Slice(0, torch::indexing::None, stride)});
    }
    const int64_t N = idx.size(0);
    out.candidates = N;
    if (N == 0) return empty();
    auto py = idx.select(1, 0), px = idx.select(1, 1);
    auto enx = nx.index({py, px}), eny = ny.index({py, px});

    // 2. Profiles across each edge, averaged along it: [N, S]; the samples' validity too.
    const int64_t S = 2 * o.reach + 1;
    auto s = torch::arange(-o.reach, o.reach + 1, torch::kFloat32).view({1, 1, S});
    auto u = torch::arange(-o.along, o.along + 1, torch::kFloat32).view({1, -1, 1});
    auto ex = enx.view({N, 1, 1}), ey = eny.view({N, 1, 1});
    auto cx = px.to(torch::kFloat32).view({N, 1, 1}) + s * ex - u * ey;
    auto cy = py.to(torch::kFloat32).view({N, 1, 1}) + s * ey + u * ex;
    auto Y = sample(L, cx, cy, false).mean(1).to(torch::kFloat64);                     // [N,S]
    auto valid = (sample(allowed, cx, cy, true).amin(1) > 0.999).to(torch::kFloat64);  // [N,S]

    // 3. Least squares of a + b·ESF over each hypothesis's window (closed form for a, b), for
    //    every (radius, offset) at once.
    std::vector<double> radii, offsets;
    auto M = edge_spread_table(kernel, o, &radii, &offsets);  // [K,S]
    const int64_t K = M.size(0), O = offsets.size();
    std::vector<double> wk(K * S);
    for (int64_t k = 0; k < K; ++k) {
        const double r = radii[k / O], s0 = offsets[k % O];
        for (int64_t j = 0; j < S; ++j)
            wk[k * S + j] = std::abs(double(j - o.reach) - s0) <= r + o.pad ? 1.0 : 0.0;
    }
    auto Wn = torch::tensor(wk, torch::kFloat64).view({K, S});
    auto WM = Wn * M, WMM = WM * M;
    auto Wt = Wn.t().contiguous(), WMt = WM.t().contiguous();
    auto Sw = Wn.sum(1), Sm = WM.sum(1), Smm = WMM.sum(1);  // [K]
    auto den = (Sw * Smm - Sm * Sm).clamp_min(1e-12);
    auto rtab = torch::tensor(radii, torch::kFloat64);
    // Edges in blocks: the [edges, K] sums of a block stay in cache (a frame's 13 000 edges
    // at once made eight 46 MB arrays, written once and faulted in each time).
    constexpr int64_t kBlock = 1024;
    std::vector<torch::Tensor> rs, res, bs;
    for (int64_t n0 = 0; n0 < N; n0 += kBlock) {
        const int64_t nb = std::min(kBlock, N - n0);
        auto Yb = Y.narrow(0, n0, nb), vb = valid.narrow(0, n0, nb);
        auto Yv = Yb * vb;
        auto Sy = torch::matmul(Yv, Wt), Sym = torch::matmul(Yv, WMt),
             Syy = torch::matmul(Yv * Yb, Wt);
        // A hypothesis whose window leaves the allowed region is not tested for this edge.
        auto outside = torch::matmul(1.0 - vb, Wt) > 0.5;  // [nb,K]
        auto b = (Sw * Sym - Sm * Sy) / den;
        auto a = (Sy - b * Sm) / Sw;
        auto rss = (Syy - a * Sy - b * Sym).clamp_min(0);
        auto nres = rss / Sw / (b * b).clamp_min(1e-12);
        nres.masked_fill_(outside, 1e30);
        auto best = nres.argmin(1);
        res.push_back(nres.gather(1, best.unsqueeze(1)).squeeze(1));
        bs.push_back(b.gather(1, best.unsqueeze(1)).squeeze(1).abs());
        rs.push_back(rtab.index({torch::div(best, O, "floor")}));
    }
    auto best_r = torch::cat(rs), best_res = torch::cat(res), best_b = torch::cat(bs);
    auto ok = (best_res < o.max_residual) & (best_b > o.min_contrast);
    out.x = px.masked_select(ok).to(torch::kFloat32);
    out.y = py.masked_select(ok).to(torch::kFloat32);
    out.radius = best_r.masked_select(ok).to(torch::kFloat32);
    out.residual = best_res.masked_select(ok).to(torch::kFloat32);
    return out;
}

}  // namespace refocus
