#include "fit/flow_warp.h"

#include <torch/nn/functional.h>
#include <torch/optim/adam.h>

#include <vector>

namespace refocus {

namespace {
namespace F = torch::nn::functional;

// [N,2] frame px → grid_sample coordinates of a corner-aligned grid over an H × W frame (the
// residual warps are upsampled with align_corners, fast_model.cpp).
torch::Tensor corner_grid(const torch::Tensor& px, int64_t H, int64_t W) {
    auto scale = torch::tensor(
        {2.0f / float(std::max<int64_t>(W - 1, 1)), 2.0f / float(std::max<int64_t>(H - 1, 1))});
    return (px * scale - 1.0).view({1, 1, -1, 2});
}

// Homography h ([3,3]) applied to [N,2] points.
torch::Tensor apply_h(const torch::Tensor& h, const torch::Tensor& p) {
    auto ph = torch::cat({p, torch::ones({p.size(0), 1})}, 1);
    auto q = torch::matmul(ph, h.t());
    return q.narrow(1, 0, 2) / q.narrow(1, 2, 1);
}

struct Pair {
    int64_t t = 0;
    torch::Tensor p, q;  // [n,2] frame px in frames t and t + 1
    torch::Tensor d;     // [n,2] h_t(p) − h_{t+1}(q), atlas px
};

torch::Tensor sample(const torch::Tensor& w, const torch::Tensor& px, int64_t H, int64_t W) {
    auto opts = F::GridSampleFuncOptions()
                    .mode(torch::kBilinear)
                    .padding_mode(torch::kBorder)
                    .align_corners(true);
    return F::grid_sample(w, corner_grid(px, H, W), opts)[0].view({2, -1}).t();  // [n,2]
}

// The flow's correspondences between neighbouring frames, in the layer in both frames, every
// `stride` px, with their disagreement through the homographies.
std::vector<Pair> collect_pairs(const torch::Tensor& to_atlas, const torch::Tensor& flow,
                                const torch::Tensor& valid,
                                const std::function<torch::Tensor(int64_t)>& region, int stride,
                                int64_t& points) {
    const int64_t T = to_atlas.size(0), H = flow.size(2), W = flow.size(3);
    std::vector<Pair> pairs;
    points = 0;
    torch::NoGradGuard no_grad;
    auto ys = torch::arange(stride / 2, H, stride, torch::kLong);
    auto xs = torch::arange(stride / 2, W, stride, torch::kLong);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto iy = g[0].flatten(), ix = g[1].flatten();
    auto lin = iy * W + ix;
    auto p_all = torch::stack({ix, iy}, 1).to(torch::kFloat32);
    auto h = to_atlas.to(torch::kFloat32);
    torch::Tensor next_region = region(0)[0];
    for (int64_t t = 0; t + 1 < T; ++t) {
        auto here = next_region;
        next_region = region(t + 1)[0];
        auto f = flow[t].reshape({2, -1}).index_select(1, lin).t();  // [N,2]
        auto ok = valid[t][0].flatten().index_select(0, lin) > 0.5;
        ok = ok & (here.flatten().index_select(0, lin) > 0.5);
        auto q = p_all + f;
        auto qx = q.select(1, 0), qy = q.select(1, 1);
        ok = ok & (qx >= 0) & (qx <= W - 1) & (qy >= 0) & (qy <= H - 1);
        auto qi = qy.round().clamp(0, H - 1).to(torch::kLong) * W +
                  qx.round().clamp(0, W - 1).to(torch::kLong);
        ok = ok & (next_region.flatten().index_select(0, qi) > 0.5);
        auto sel = ok.nonzero().flatten();
        if (sel.numel() == 0) continue;
        Pair pr;
        pr.t = t;
        pr.p = p_all.index_select(0, sel);
        pr.q = q.index_select(0, sel);
        pr.d = apply_h(h[t], pr.p) - apply_h(h[t + 1], pr.q);
        points += sel.numel();
        pairs.push_back(std::move(pr));
    }
    return pairs;
}

}  // namespace

FlowWarpResult warps_from_flow(const torch::Tensor& to_atlas, double scale,
                               const torch::Tensor& flow, const torch::Tensor& valid,
                               const std::function<torch::Tensor(int64_t)>& region, int64_t gh,
                               int64_t gw, int iters, int stride) {
    const int64_t T = to_atlas.size(0), H = flow.size(2), W = flow.size(3);
    FlowWarpResult res;
    res.warp = torch::zeros({T, 2, gh, gw});
    if (T < 2 || flow.size(0) != T - 1) return res;
    const std::vector<Pair> pairs =
        collect_pairs(to_atlas, flow, valid, region, stride, res.points);
    if (res.points == 0) return res;
    torch::AutoGradMode grad(true);  // the model is built under a NoGradGuard
    auto w = torch::zeros({T, 2, gh, gw}, torch::requires_grad());
    const double smooth = 0.01, size = 1e-4, eps2 = 0.25;
    auto disagreement = [&](bool robust) {
        torch::Tensor sum = torch::zeros({});
        for (const auto& pr : pairs) {
            auto wp = sample(w[pr.t].unsqueeze(0), pr.p, H, W);
            auto wq = sample(w[pr.t + 1].unsqueeze(0), pr.q, H, W);
            auto r = pr.d + scale * (wp - wq);
            auto n2 = r.pow(2).sum(1);
            sum = sum + (robust ? (n2 + eps2).sqrt() : n2.sqrt()).sum();
        }
        return sum / double(res.points);
    };
    {
        torch::NoGradGuard no_grad;
        res.before_px = disagreement(false).item<double>();
    }
    torch::optim::Adam opt({w}, torch::optim::AdamOptions(0.3));
    for (int i = 0; i < iters; ++i) {
        opt.zero_grad();
        auto dx = w.narrow(3, 1, gw - 1) - w.narrow(3, 0, gw - 1);
        auto dy = w.narrow(2, 1, gh - 1) - w.narrow(2, 0, gh - 1);
        auto loss = disagreement(true) + smooth * (dx.pow(2).mean() + dy.pow(2).mean()) +
                    size * w.pow(2).mean();
        loss.backward();
        opt.step();
    }
    torch::NoGradGuard done;
    res.after_px = disagreement(false).item<double>();
    res.warp = w.detach().clone();

    return res;
}

ParallaxInit parallax_from_flow(const torch::Tensor& to_atlas, const torch::Tensor& flow,
                                const torch::Tensor& valid,
                                const std::function<torch::Tensor(int64_t)>& region,
                                const torch::Tensor& epipole, const torch::Tensor& centre,
                                double radius, int64_t atlas_w, int64_t atlas_h, int64_t gh,
                                int64_t gw, double min_held_gain, int iters, int stride,
                                bool correct_homographies) {
    const int64_t T = to_atlas.size(0);
    ParallaxInit res;
    res.parallax = torch::zeros({1, 1, gh, gw});
    res.epipole = epipole.clone();
    if (T < 2 || flow.size(0) != T - 1) return res;
    const std::vector<Pair> pairs =
        collect_pairs(to_atlas, flow, valid, region, stride, res.points);
    if (res.points == 0) return res;
    // Each correspondence's atlas point (frame t's, through its homography) and where it reads γ.
    std::vector<torch::Tensor> at, grid;
    const auto norm = torch::tensor({2.0f / float(atlas_w), 2.0f / float(atlas_h)});
    {
        torch::NoGradGuard no_grad;
        auto h = to_atlas.to(torch::kFloat32);
        for (const auto& pr : pairs) {
            at.push_back(apply_h(h[pr.t], pr.p));
            grid.push_back(((at.back() + 0.5) * norm - 1.0).view({1, 1, -1, 2}));
        }
    }
    torch::AutoGradMode grad(true);  // the model is built under a NoGradGuard
    auto g = torch::zeros({1, 1, gh, gw}, torch::requires_grad());
    auto e = epipole.clone().set_requires_grad(true);
    // Each frame's homography corrected by an affine map in px at the frame's half diagonal R
    // (b_x, b_y, M): chained pairwise homographies each take their own mix of depths for the
    // plane and drift over a clip, which one γ shared by every frame cannot take.
    auto corr = torch::zeros({T, 6}, torch::requires_grad(correct_homographies));
    auto keep0 = torch::ones({T, 1});
    keep0[0] = 0;
    const auto mid = torch::tensor({0.5f * float(atlas_w), 0.5f * float(atlas_h)}).view({2, 1});
    // C_t(u) = u + b_t + M_t·(u − c)/R as [T,2,3] rows (A_t | s_t): A = I + M/R, s = b − M·c/R.
    auto correction_maps = [&] {
        auto c = corr * keep0;
        auto m = c.narrow(1, 2, 4).view({T, 2, 2}) / radius;
        auto shift = c.narrow(1, 0, 2).view({T, 2, 1}) - torch::matmul(m, mid);
        return torch::cat({torch::eye(2).expand({T, 2, 2}) + m, shift}, 2);
    };
    bool use_corr = false;
    torch::Tensor maps;  // correction_maps() for the disagreement being summed
    auto corrected = [&](int64_t t, const torch::Tensor& u) {  // C_t(u), u [n,2]
        if (!use_corr) return u;
        return torch::matmul(u, maps[t].narrow(1, 0, 2).t()) + maps[t].narrow(1, 2, 1).t();
    };
    // γ is a property of the scene with edges where depth jumps (a pillar before a wall): a
    // lighter smoothness than the warps', whose grid is per frame.
    const double smooth = 0.001, size = 1e-4, eps2 = 0.25;
    const auto opts = F::GridSampleFuncOptions()
                          .mode(torch::kBilinear)
                          .padding_mode(torch::kBorder)
                          .align_corners(false);
    // h_t(p) − h_{t+1}(q) = γ(u)·(d_{t+1}(u) − d_t(u)), d_t(u) = a_t + b_t·(u − c_t)/R.
    // parity: every pair (−1), or the pairs whose t is even (0) or odd (1).
    auto disagreement = [&](bool robust, int parity) {
        torch::Tensor sum = torch::zeros({});
        int64_t n = 0;
        if (use_corr) maps = correction_maps();
        for (size_t i = 0; i < pairs.size(); ++i) {
            const auto& pr = pairs[i];
            if (parity >= 0 && pr.t % 2 != parity) continue;
            const auto u = corrected(pr.t, at[i]);
            const auto gr = use_corr ? ((u + 0.5) * norm - 1.0).view({1, 1, -1, 2}) : grid[i];
            auto gam = F::grid_sample(g, gr, opts).view({-1, 1});  // [n,1]
            auto dir = [&](int64_t t) {
                return e[t].narrow(0, 0, 2).view({1, 2}) +
                       e[t].narrow(0, 2, 1).view({1, 1}) * (u - centre[t].view({1, 2})) / radius;
            };
            auto d = use_corr ? u - corrected(pr.t + 1, at[i] - pr.d) : pr.d;
            auto r = d - gam * (dir(pr.t + 1) - dir(pr.t));
            auto n2 = r.pow(2).sum(1);
            sum = sum + (robust ? (n2 + eps2).sqrt() : n2.sqrt()).sum();
            n += pr.p.size(0);
        }
        return sum / double(std::max<int64_t>(1, n));
    };
    torch::optim::Adam opt_g({g}, torch::optim::AdamOptions(0.3));
    torch::optim::Adam opt_e({e}, torch::optim::AdamOptions(0.0));
    torch::optim::Adam opt_c({corr}, torch::optim::AdamOptions(0.05));
    auto fit = [&](int parity, int steps) {
        for (int i = 0; i < steps; ++i) {
            opt_g.zero_grad();
            opt_e.zero_grad();
            opt_c.zero_grad();
            auto dx = g.narrow(3, 1, gw - 1) - g.narrow(3, 0, gw - 1);
            auto dy = g.narrow(2, 1, gh - 1) - g.narrow(2, 0, gh - 1);
            auto loss = disagreement(true, parity) +
                        smooth * (dx.pow(2).mean() + dy.pow(2).mean()) + size * g.pow(2).mean();
            loss.backward();
            opt_g.step();
            opt_e.step();
            if (use_corr) opt_c.step();
        }
    };
    {
        torch::NoGradGuard no_grad;
        res.before_px = disagreement(false, -1).item<double>();
    }
    int even = 0, odd = 0;
    for (const auto& pr : pairs) (pr.t % 2 ? odd : even) += 1;
    if (even >= 2 && odd >= 2) {  // held out: fitted to the even pairs, scored on the odd
        {
            torch::NoGradGuard no_grad;
            res.held_before_px = disagreement(false, 1).item<double>();
        }
        fit(0, iters / 2);
        torch::NoGradGuard no_grad;
        res.held_after_px = disagreement(false, 1).item<double>();
    }
    if (min_held_gain > 0 && !(res.held_gain() >= min_held_gain))
        return res;  // refused (or not scored): the caller keeps no field, so fit no further
    use_corr = correct_homographies;
    fit(-1, iters);
    torch::NoGradGuard done;
    res.after_px = disagreement(false, -1).item<double>();
    res.parallax = g.detach().clone();
    res.epipole = e.detach().clone();
    if (use_corr) {
        auto m = correction_maps().to(torch::kFloat64);
        res.correction = torch::cat(
            {m, torch::tensor({0.0, 0.0, 1.0}, torch::kFloat64).view({1, 1, 3}).expand({T, 1, 3})},
            1);
    }
    return res;
}

}  // namespace refocus
