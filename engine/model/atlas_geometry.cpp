#include "model/atlas_geometry.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include "model/fit_model.h"
#include "ops/morphology.h"
#include "util/debug.h"
#include "util/error.h"
#include "util/threads.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace refocus {

torch::Tensor translation(double tx, double ty) {
    auto m = torch::eye(3, torch::kFloat64);
    m[0][2] = tx;
    m[1][2] = ty;
    return m;
}

AtlasBox mapped_frames_box(const torch::Tensor& to_ref_in, int64_t H, int64_t W) {
    auto to_ref = to_ref_in.to(torch::kFloat64).contiguous();
    double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
    for (int64_t t = 0; t < to_ref.size(0); ++t)
        for (double cy : {0.0, H / 2.0, double(H - 1)})
            for (double cx : {0.0, W / 2.0, double(W - 1)}) {
                auto p = torch::matmul(to_ref[t], torch::tensor({cx, cy, 1.0}, torch::kFloat64));
                const double px = p[0].item<double>() / p[2].item<double>();
                const double py = p[1].item<double>() / p[2].item<double>();
                x0 = std::min(x0, px), x1 = std::max(x1, px);
                y0 = std::min(y0, py), y1 = std::max(y1, py);
            }
    x0 = std::max(x0, -double(W)), y0 = std::max(y0, -double(H));
    x1 = std::min(x1, 2.0 * W), y1 = std::min(y1, 2.0 * H);
    AtlasBox b;
    b.origin_x = std::floor(x0) - 2;
    b.origin_y = std::floor(y0) - 2;
    b.width = static_cast<int64_t>(std::ceil(x1) - b.origin_x) + 3;
    b.height = static_cast<int64_t>(std::ceil(y1) - b.origin_y) + 3;
    return b;
}

namespace {
void track_from_masks(const FitData& d, std::vector<double>& vx, std::vector<double>& vy,
                      std::vector<double>* scale_out) {
    const torch::Tensor &flow_fwd = d.flow_fwd, &flow_valid = d.flow_valid;
    auto m = d.mask.squeeze(1);  // [T,H,W]
    const int64_t T = m.size(0);
    auto ys = torch::arange(m.size(1), torch::kFloat32),
         xs = torch::arange(m.size(2), torch::kFloat32);
    auto grid = torch::meshgrid({ys, xs}, "ij");
    // Frame by frame: a long clip's masks are a file mapping (util/mapped.h).
    // A frame a core: each frame's sums are made on one thread, whatever the thread count.
    std::vector<double> mass(T), cx(T), cy(T);
    at::parallel_for(0, T, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            const auto mt = m[t];
            mass[t] = std::max(mt.sum().item<double>(), 1e-6);
            cx[t] = (mt * grid[1]).sum().item<double>() / mass[t];
            cy[t] = (mt * grid[0]).sum().item<double>() / mass[t];
        }
    });
    std::vector<double> rx(T), ry(T);
    int64_t last = -1;
    for (int64_t t = 0; t < T; ++t) {
        if (mass[t] > 4.0) last = t;
        rx[t] = cx[last < 0 ? t : last];
        ry[t] = cy[last < 0 ? t : last];
    }
    vx.assign(T, 0.0);
    vy.assign(T, 0.0);
    if (scale_out) scale_out->assign(T, 1.0);
    const bool have_flow =
        flow_fwd.defined() && flow_fwd.size(0) == T - 1 && T > 1 && !d.legacy_subject_track;
    if (!have_flow) {
        for (int64_t t = 0; t < T; ++t) {
            double ax = 0, ay = 0;
            int n = 0;
            for (int64_t k = std::max<int64_t>(0, t - 2); k <= std::min<int64_t>(T - 1, t + 2); ++k)
                ax += rx[k], ay += ry[k], ++n;
            vx[t] = ax / n;
            vy[t] = ay / n;
        }
        return;
    }
    // The subject's own motion: the median flow over its mask (eroded off the wall it moves
    // against, where the flow is consistent), chained. The masks' outline is what focus changes
    // most: a blurred subject's thresholded mask grows, shrinks and loses its head, so its
    // centroid wanders where the flow chain does not. Not ECC between pairs: the sharp wall
    // showing through a blurred subject's edge pulls it toward the wall's motion
    // (docs/method.md, Preparation).
    auto core = [&](int64_t t) {
        return min_filter((m[t] > 0.5).to(torch::kFloat32).view({1, 1, m.size(1), m.size(2)}), 4)
                   .view({m.size(1), m.size(2)}) > 0.5;
    };
    std::vector<double> sx(T, 0.0), sy(T, 0.0);
    // With the scale (a subject walking toward or away from the camera): frame t's point p is
    // at v_{t+1} + s_t (p − v_t) in frame t + 1, s_t the least-squares expansion of the flow
    // about the core's centre c_t, so v_{t+1} = c_t + f̄_t − s_t (c_t − v_t).
    std::vector<double> zx(T), zy(T), zs(T, 1.0);
    zx[0] = rx[0], zy[0] = ry[0];
    // Each pair's step measured on the cores (a pair reads its own flow and mask), then chained.
    struct Step {
        bool measured = false;
        double dx = 0, dy = 0, st = 1.0, ccx = 0, ccy = 0, zdx = 0, zdy = 0;
    };
    std::vector<Step> steps(std::max<int64_t>(T - 1, 0));
    at::parallel_for(0, T - 1, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            auto sel = core(t);
            if (flow_valid.defined()) sel = sel & (flow_valid[t][0] > 0.5);
            if (sel.sum().item<int64_t>() < 32) continue;
            Step& p = steps[t];
            p.measured = true;
            auto fx = flow_fwd[t][0].masked_select(sel), fy = flow_fwd[t][1].masked_select(sel);
            p.dx = fx.median().item<double>();
            p.dy = fy.median().item<double>();
            auto px = grid[1].masked_select(sel).to(torch::kFloat64),
                 py = grid[0].masked_select(sel).to(torch::kFloat64);
            p.ccx = px.mean().item<double>(), p.ccy = py.mean().item<double>();
            auto qx = px - p.ccx, qy = py - p.ccy;
            const double den = (qx * qx + qy * qy).sum().item<double>();
            if (den > 1e-6)
                p.st = 1.0 + ((qx * (fx.to(torch::kFloat64) - p.dx)) +
                              (qy * (fy.to(torch::kFloat64) - p.dy)))
                                     .sum()
                                     .item<double>() /
                                 den;
            p.st = std::clamp(p.st, 0.8, 1.25);
            // The flow at the core's centre: the median once the expansion is taken out.
            p.zdx = (fx.to(torch::kFloat64) - (p.st - 1.0) * qx).median().item<double>();
            p.zdy = (fy.to(torch::kFloat64) - (p.st - 1.0) * qy).median().item<double>();
        }
    });
    for (int64_t t = 0; t + 1 < T; ++t) {
        double dx, dy, st = 1.0, ccx = rx[t], ccy = ry[t], zdx, zdy;
        if (steps[t].measured) {
            const Step& p = steps[t];
            dx = p.dx, dy = p.dy, st = p.st, ccx = p.ccx, ccy = p.ccy, zdx = p.zdx, zdy = p.zdy;
        } else if (t > 0 && !d.legacy_track_gaps) {
            // No measurable subject (its mask is missing): the previous step again. The masks'
            // centroids hold the last one seen there, and stepping by them after the gap adds
            // the gap's motion twice (as the "flow" track, FitData::legacy_track_gaps, does).
            dx = sx[t] - sx[t - 1];
            dy = sy[t] - sy[t - 1];
            st = zs[t] / zs[t - 1];
            ccx = zx[t], ccy = zy[t];  // about the track point: z_{t+1} = z_t + (z_t − z_{t−1})
            zdx = zx[t] - zx[t - 1];
            zdy = zy[t] - zy[t - 1];
        } else {  // the centroids' step
            dx = zdx = rx[t + 1] - rx[t];
            dy = zdy = ry[t + 1] - ry[t];
        }
        sx[t + 1] = sx[t] + dx;
        sy[t + 1] = sy[t] + dy;
        zs[t + 1] = zs[t] * st;
        zx[t + 1] = ccx + zdx - st * (ccx - zx[t]);
        zy[t + 1] = ccy + zdy - st * (ccy - zy[t]);
    }
    // The scale is used where the subject's size changes by more than 30% over the clip: noise
    // in each pair's expansion chains, drifting by up to ~11% on a subject that keeps its depth
    // (docs/method.md, Preparation).
    const double smax = *std::max_element(zs.begin(), zs.end()),
                 smin = *std::min_element(zs.begin(), zs.end());
    if (scale_out && smax > 1.3 * smin) {
        for (int64_t t = 0; t < T; ++t) {
            vx[t] = zx[t], vy[t] = zy[t];
            (*scale_out)[t] = zs[t] / smax;  // the atlas holds the largest view at 1:1
        }
        return;
    }
    // Anchored where the masks put the subject, on the median over the clip.
    std::vector<double> ox(T), oy(T);
    for (int64_t t = 0; t < T; ++t) ox[t] = rx[t] - sx[t], oy[t] = ry[t] - sy[t];
    std::nth_element(ox.begin(), ox.begin() + T / 2, ox.end());
    std::nth_element(oy.begin(), oy.begin() + T / 2, oy.end());
    for (int64_t t = 0; t < T; ++t) vx[t] = sx[t] + ox[T / 2], vy[t] = sy[t] + oy[T / 2];
}
}  // namespace

int64_t version(const torch::Tensor& t) {
    return t.defined() ? int64_t(t._version()) : -1;
}

void subject_track(const FitData& d, std::vector<double>& vx, std::vector<double>& vy,
                   std::vector<double>* scale_out) {
    // Reading a long clip's masks and flow is most of it, and set-up asks more than once.
    const bool scaled = scale_out != nullptr;
    for (const FitData::TrackMemo& m : d.track_memo)
        if (m.mask.is_same(d.mask) && m.flow.is_same(d.flow_fwd) && m.scaled == scaled &&
            m.versions == std::make_pair(version(d.mask), version(d.flow_fwd)) &&
            m.legacy == d.legacy_subject_track && m.gaps == d.legacy_track_gaps) {
            vx = m.vx, vy = m.vy;
            if (scale_out) *scale_out = m.scale;
            return;
        }
    FitData::TrackMemo m{d.mask,
                         d.flow_fwd,
                         scaled,
                         d.legacy_subject_track,
                         d.legacy_track_gaps,
                         {version(d.mask), version(d.flow_fwd)}};
    track_from_masks(d, m.vx, m.vy, scaled ? &m.scale : nullptr);
    vx = m.vx, vy = m.vy;
    if (scale_out) *scale_out = m.scale;
    d.track_memo.push_back(std::move(m));
}

torch::Tensor subject_to_track(double vx, double vy, double scale) {
    auto m = torch::eye(3, torch::kFloat64);
    m[0][0] = m[1][1] = 1.0 / scale;
    m[0][2] = -vx / scale;
    m[1][2] = -vy / scale;
    return m;
}

AtlasBox subject_box(const torch::Tensor& mask, const std::vector<double>& vx,
                     const std::vector<double>& vy, double margin,
                     const std::vector<double>* scale) {
    auto m = mask.squeeze(1);
    const int64_t T = m.size(0), H = m.size(1), W = m.size(2);
    double fx0 = 1e30, fy0 = 1e30, fx1 = -1e30, fy1 = -1e30;
    for (int64_t t = 0; t < T; ++t) {
        auto nz = torch::nonzero(m[t] > 0.05);
        if (nz.size(0) == 0) continue;
        auto mn = std::get<0>(nz.min(0)), mx = std::get<0>(nz.max(0));
        const double k = scale ? 1.0 / (*scale)[t] : 1.0;
        fy0 = std::min(fy0, (mn[0].item<double>() - vy[t]) * k);
        fx0 = std::min(fx0, (mn[1].item<double>() - vx[t]) * k);
        fy1 = std::max(fy1, (mx[0].item<double>() - vy[t]) * k);
        fx1 = std::max(fx1, (mx[1].item<double>() - vx[t]) * k);
    }
    if (fx0 > fx1) fx0 = -W / 4.0, fx1 = W / 4.0, fy0 = -H / 4.0, fy1 = H / 4.0;
    AtlasBox b;
    b.origin_x = std::floor(fx0) - margin;
    b.origin_y = std::floor(fy0) - margin;
    b.width = static_cast<int64_t>(std::ceil(fx1) - b.origin_x + margin) + 1;
    b.height = static_cast<int64_t>(std::ceil(fy1) - b.origin_y + margin) + 1;
    return b;
}

torch::Tensor sharpness_weight(const torch::Tensor& radius) {
    auto x = radius + 0.5;
    x.mul_(x);
    x.mul_(x);
    return x.reciprocal_();
}

torch::Tensor sample_bicubic(const torch::Tensor& input, const torch::Tensor& grid) {
    return torch::grid_sampler(input, grid, /*interpolation_mode=*/2, /*padding_mode=*/1,
                               /*align_corners=*/false);
}

namespace {

// Whether the frame → atlas homography m [3,3] is a translation by whole pixels (dx, dy).
bool whole_pixel_shift(const torch::Tensor& m, int64_t& dx, int64_t& dy) {
    const auto d = m.to(torch::kFloat64).contiguous();
    const double* a = d.data_ptr<double>();
    const double e = 1e-6;
    if (std::abs(a[0] - 1) > e || std::abs(a[1]) > e || std::abs(a[3]) > e ||
        std::abs(a[4] - 1) > e || std::abs(a[6]) > e || std::abs(a[7]) > e ||
        std::abs(a[8] - 1) > e)
        return false;
    const double rx = std::round(a[2]), ry = std::round(a[5]);
    if (std::abs(a[2] - rx) > 1e-4 || std::abs(a[5] - ry) > 1e-4) return false;
    dx = int64_t(rx), dy = int64_t(ry);
    return true;
}

// The texels a W × H frame mapped by m [3,3] reaches, grown by 2 (bicubic taps): its corners'
// box; the whole atlas where a corner maps through infinity.
TexelBox footprint(const torch::Tensor& m, int64_t W, int64_t H, int64_t width, int64_t height) {
    auto c = torch::tensor(
                 {-0.5, W - 0.5, -0.5, W - 0.5, -0.5, -0.5, H - 0.5, H - 0.5, 1.0, 1.0, 1.0, 1.0},
                 torch::kFloat64)
                 .view({3, 4});
    if (!(torch::matmul(m.to(torch::kFloat64), c)[2] > 1e-9).all().item<bool>())
        return TexelBox{0, 0, width, height};
    return mapped_box(m.unsqueeze(0), 0, -0.5, -0.5, W - 0.5, H - 0.5, 2.0, height, width);
}

}  // namespace

torch::Tensor fuse_frames(const torch::Tensor& to_atlas, int64_t height, int64_t width,
                          const torch::Tensor& src, const torch::Tensor& weight) {
    return fuse_frames(
        to_atlas, height, width, [&](int64_t t) { return src[t]; },
        [&](int64_t t) { return weight[t]; });
}

TexelBox mapped_box(const torch::Tensor& to_atlas, int64_t t, double x0, double y0, double x1,
                    double y1, double grow, int64_t height, int64_t width) {
    auto m = to_atlas[t].to(torch::kFloat64);
    auto c = torch::tensor({x0, x1, x0, x1, y0, y0, y1, y1, 1.0, 1.0, 1.0, 1.0}, torch::kFloat64)
                 .view({3, 4});
    auto p = torch::matmul(m, c);
    auto xy = p.narrow(0, 0, 2) / p.narrow(0, 2, 1);
    const auto lo = std::get<0>(xy.min(1)), hi = std::get<0>(xy.max(1));
    const int64_t bx0 = std::max<int64_t>(0, int64_t(std::floor(lo[0].item<double>() - grow))),
                  by0 = std::max<int64_t>(0, int64_t(std::floor(lo[1].item<double>() - grow))),
                  bx1 =
                      std::min<int64_t>(width - 1, int64_t(std::ceil(hi[0].item<double>() + grow))),
                  by1 = std::min<int64_t>(height - 1,
                                          int64_t(std::ceil(hi[1].item<double>() + grow)));
    TexelBox b;
    if (bx1 < bx0 || by1 < by0) return b;
    b.x0 = bx0, b.y0 = by0, b.w = bx1 - bx0 + 1, b.h = by1 - by0 + 1;
    return b;
}

torch::Tensor fuse_frames(const torch::Tensor& to_atlas, int64_t height, int64_t width,
                          const std::function<torch::Tensor(int64_t)>& src,
                          const std::function<torch::Tensor(int64_t)>& weight,
                          const std::function<torch::Tensor(int64_t)>& offset,
                          const std::function<TexelBox(int64_t)>& window,
                          const torch::Tensor& fallback, bool shortcuts) {
    namespace F = torch::nn::functional;
    const int64_t T = to_atlas.size(0);
    auto ys = torch::arange(height, torch::kFloat32), xs = torch::arange(width, torch::kFloat32);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto pts = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({height * width})}, 0);
    auto opts = F::GridSampleFuncOptions()
                    .mode(torch::kBilinear)
                    .padding_mode(torch::kZeros)
                    .align_corners(false);
    // The frames in two interleaved sums (t even, t odd), one a core (for_each_in_parts): the
    // same result on any machine.
    struct Sum {
        torch::Tensor acc, wsum, ones, scale;
    };
    constexpr int kSums = 2;
    Sum sums[kSums];
    auto add_frame = [&](int64_t t, Sum& sum) {
        // The whole atlas, or the frame's window of it.
        TexelBox box{0, 0, width, height};
        if (window) {
            box = window(t);
            if (box.w <= 0 || box.h <= 0) return;
        }
        const torch::Tensor s = src(t);
        torch::Tensor &acc = sum.acc, &wsum = sum.wsum, &ones = sum.ones, &scale = sum.scale;
        if (!acc.defined()) {  // every frame has the first one's size
            const int64_t C = s.size(0), H = s.size(1), W = s.size(2);
            acc = torch::zeros({C, height, width});
            wsum = torch::zeros({1, height, width});
            ones = torch::ones({1, 1, H, W});
            scale = torch::tensor({2.0f / W, 2.0f / H});
        }
        // A frame that lands on the atlas by a whole-pixel shift (a static camera's background at
        // scale 1) is added as it is: the samplers would read its pixel centres exactly.
        int64_t dx = 0, dy = 0;
        if (shortcuts && !offset && whole_pixel_shift(to_atlas[t], dx, dy)) {
            const int64_t H = s.size(1), W = s.size(2);
            const int64_t x0 = std::max(box.x0, dx), y0 = std::max(box.y0, dy),
                          x1 = std::min(box.x0 + box.w, dx + W),
                          y1 = std::min(box.y0 + box.h, dy + H);
            if (x1 <= x0 || y1 <= y0) return;
            auto cut = [&](const torch::Tensor& x) {
                return x.narrow(1, y0 - dy, y1 - y0).narrow(2, x0 - dx, x1 - x0);
            };
            const auto w = cut(weight(t));
            acc.narrow(1, y0, y1 - y0).narrow(2, x0, x1 - x0) += cut(s) * w;
            wsum.narrow(1, y0, y1 - y0).narrow(2, x0, x1 - x0) += w;
            return;
        }
        // Without a window, the frame's footprint (its corners' box, grown by the bicubic
        // taps): texels past it read nothing of the frame, and a subject's atlas spans its whole
        // track (1920x1080x240 walkers: 2.4 frames).
        if (shortcuts && !window && !offset &&
            !(box = footprint(to_atlas[t], s.size(2), s.size(1), width, height)).w)
            return;
        torch::Tensor at = pts;
        if (box.w != width || box.h != height) {
            at = pts.view({3, height, width})
                     .narrow(1, box.y0, box.h)
                     .narrow(2, box.x0, box.w)
                     .reshape({3, -1});
        }
        auto inv = torch::inverse(to_atlas[t].to(torch::kFloat64)).to(torch::kFloat32);
        auto p = torch::matmul(inv, at);
        auto xy = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1)).t().view({1, box.h, box.w, 2});
        auto grid = (xy + 0.5) * scale - 1.0;
        if (offset) {
            if (window) throw Error("fuse_frames: windows with a residual warp are not supported");
            const auto off = offset(t).unsqueeze(0);  // [1,2,H,W]
            auto border = F::GridSampleFuncOptions()
                              .mode(torch::kBilinear)
                              .padding_mode(torch::kBorder)
                              .align_corners(false);
            for (int k = 0; k < 3; ++k) {
                auto o = F::grid_sample(off, grid, border)[0].view({2, -1});
                auto a = torch::cat({pts.narrow(0, 0, 2) - o, pts.narrow(0, 2, 1)}, 0);
                auto q = torch::matmul(inv, a);
                xy = (q.narrow(0, 0, 2) / q.narrow(0, 2, 1)).t().view({1, height, width, 2});
                grid = (xy + 0.5) * scale - 1.0;
            }
        }
        auto inside = F::grid_sample(ones, grid, opts)[0];
        auto col = sample_bicubic(s.unsqueeze(0), grid)[0];
        auto w = F::grid_sample(weight(t).unsqueeze(0), grid, opts)[0] * (inside > 0.999);
        acc.narrow(1, box.y0, box.h).narrow(2, box.x0, box.w) += col * w;
        wsum.narrow(1, box.y0, box.h).narrow(2, box.x0, box.w) += w;
    };
    for_each_in_parts(T, kSums, [&](int64_t t, int p) { add_frame(t, sums[p]); });
    torch::Tensor acc, wsum;
    for (const Sum& sum : sums) {
        if (!sum.acc.defined()) continue;
        acc = acc.defined() ? acc + sum.acc : sum.acc;
        wsum = wsum.defined() ? wsum + sum.wsum : sum.wsum;
    }
    if (!acc.defined()) return fallback.defined() ? fallback : torch::zeros({1, height, width});
    auto mean = fallback.defined()
                    ? fallback
                    : (acc.sum({1, 2}, true) / wsum.sum().clamp_min(1e-12)).expand_as(acc);
    return torch::where(wsum > 1e-8, acc / wsum.clamp_min(1e-8), mean);
}

}  // namespace refocus

namespace refocus {

std::string clean_subject_masks(FitData& d, double min_persistence) {
    if (!d.has_subject || !d.mask.defined() || d.frames < 3) return {};
    torch::NoGradGuard no_grad;
    namespace F = torch::nn::functional;
    const int64_t T = d.frames, H = d.height, W = d.width;
    std::vector<double> vx, vy, sc;
    subject_track(d, vx, vy, &sc);
    auto bin = (d.mask.squeeze(1) > 0.5).to(torch::kUInt8).contiguous();  // [T,H,W]
    const uint8_t* mb = bin.data_ptr<uint8_t>();
    auto at = [&](int64_t u, double x, double y) -> int {  // -1 outside the frame
        const long xi = std::lround(x), yi = std::lround(y);
        if (xi < 0 || yi < 0 || xi >= W || yi >= H) return -1;
        return mb[(u * H + yi) * W + xi];
    };
    const bool debug = debug_enabled("masks");
    int dropped = 0, filled = 0;
    std::vector<double> area(T, 0.0);
    // The cleaned masks, frame by frame into a clip array (a long clip's need not fit in memory);
    // d.mask itself is left as it was (mask_as_stored may share it).
    torch::Tensor kept = d.clip_array(d.mask.sizes(), "mask");
    // A part's persistence is read in 33 frames spread over the clip (all of a shorter clip's):
    // a share, which 32 samples hold to a few percent, where every pair of 240 frames is T² work.
    std::vector<int64_t> others;
    for (int64_t i = 0, n = std::min<int64_t>(T, 33); i < n; ++i)
        others.push_back(n == T ? i : std::llround(double(i) * double(T - 1) / double(n - 1)));
    // Frame by frame on the cores: a frame's parts read the binary masks only.
    std::vector<int> dropped_in(T, 0);
    at::parallel_for(0, T, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            cv::Mat m(int(H), int(W), CV_8U, const_cast<uint8_t*>(mb + t * H * W));
            cv::Mat labels, stats, centroids;
            const int n = cv::connectedComponentsWithStats(m, labels, stats, centroids, 8, CV_32S);
            cv::Mat keep = cv::Mat::zeros(int(H), int(W), CV_8U);
            for (int k = 1; k < n; ++k) {
                // How often the other frames' masks hold this part's pixels at the same place on
                // the subject (moved along the track); a pixel that leaves a frame does not count
                // there.
                int64_t hits = 0, seen = 0;
                const int x0 = stats.at<int>(k, cv::CC_STAT_LEFT),
                          y0 = stats.at<int>(k, cv::CC_STAT_TOP);
                const int w = stats.at<int>(k, cv::CC_STAT_WIDTH),
                          h = stats.at<int>(k, cv::CC_STAT_HEIGHT);
                for (int y = y0; y < y0 + h; y += 2)
                    for (int x = x0; x < x0 + w; x += 2) {
                        if (labels.at<int>(y, x) != k) continue;
                        for (const int64_t u : others) {
                            if (u == t) continue;
                            const double f = sc[u] / sc[t];
                            const int v = at(u, (x - vx[t]) * f + vx[u], (y - vy[t]) * f + vy[u]);
                            if (v < 0) continue;
                            ++seen;
                            hits += v;
                        }
                    }
                const double pers = seen ? double(hits) / double(seen) : 1.0;
                const int a = stats.at<int>(k, cv::CC_STAT_AREA);
                if (debug)
                    std::fprintf(stderr, "mask %lld part %d: %d px at (%d,%d) persistence %.2f\n",
                                 (long long)t, k, a, x0, y0, pers);
                if (pers < min_persistence) {
                    ++dropped_in[t];
                    continue;
                }
                keep.setTo(255, labels == k);
                area[t] += a;
            }
            // Kept parts with their soft edge (the mask's values within 2 px of them).
            cv::dilate(keep, keep, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(5, 5)));
            auto kt =
                torch::from_blob(keep.data, {1, H, W}, torch::kUInt8).to(torch::kFloat32) / 255.0;
            kept[t].copy_(d.mask[t] * kt);
        }
    });
    for (const int n : dropped_in) dropped += n;
    // A frame whose mask lost most of the subject (under 30% of the clip's median area, at the
    // subject's size in that frame) takes the nearest frame's that holds it (over 50%), moved
    // along the track, where that covers at least twice as much of the frame (a subject leaving
    // the frame loses area the moved mask loses too).
    std::vector<double> norm(T), nz;
    for (int64_t t = 0; t < T; ++t) {
        norm[t] = area[t] / (sc[t] * sc[t]);
        if (norm[t] > 0) nz.push_back(norm[t]);
    }
    if (!nz.empty()) {
        std::nth_element(nz.begin(), nz.begin() + nz.size() / 2, nz.end());
        const double med = nz[nz.size() / 2];
        std::vector<int64_t> good;
        for (int64_t t = 0; t < T; ++t)
            if (norm[t] >= 0.5 * med) good.push_back(t);
        auto ys = torch::arange(H, torch::kFloat64), xs = torch::arange(W, torch::kFloat64);
        auto g = torch::meshgrid({ys, xs}, "ij");
        // A frame a core: a frame refilled (under 0.3 of the median) is never one that lends
        // its mask (over 0.5), so each reads masks no other writes.
        std::vector<char> filled_in(T, 0);
        at::parallel_for(0, good.empty() ? 0 : T, 1, [&](int64_t t0, int64_t t1) {
            for (int64_t t = t0; t < t1; ++t) {
                if (norm[t] >= 0.3 * med) continue;
                int64_t u = good.front();
                for (int64_t k : good)
                    if (std::abs(k - t) < std::abs(u - t)) u = k;
                // Frame t's pixel p is frame u's (p − c_t)·s_u/s_t + c_u (grid_sample,
                // align_corners false).
                const double f = sc[u] / sc[t];
                auto px = (g[1] - vx[t]) * f + vx[u], py = (g[0] - vy[t]) * f + vy[u];
                auto grid =
                    torch::stack({(px + 0.5) * (2.0 / W) - 1.0, (py + 0.5) * (2.0 / H) - 1.0}, -1)
                        .to(torch::kFloat32)
                        .unsqueeze(0);
                auto moved = F::grid_sample(kept[u].unsqueeze(0), grid,
                                            F::GridSampleFuncOptions()
                                                .mode(torch::kBilinear)
                                                .padding_mode(torch::kZeros)
                                                .align_corners(false))[0];
                const double moved_area = (moved > 0.5).sum().item<double>();
                if (debug)
                    std::fprintf(stderr,
                                 "mask %lld: %.0f px (median %.0f at its size), frame %lld's moved "
                                 "onto it %.0f px\n",
                                 (long long)t, area[t], med * sc[t] * sc[t], (long long)u,
                                 moved_area);
                if (moved_area < 2.0 * area[t] || moved_area < 16) continue;
                kept[t].copy_(moved);
                filled_in[t] = 1;
            }
        });
        for (const char f : filled_in) filled += f;
    }
    d.mask = kept;
    char line[240];
    std::snprintf(
        line, sizeof line,
        "masks: %d part(s) that the other frames do not hold on the subject dropped, %d frame(s) "
        "that lost the subject given their neighbour's mask along its track",
        dropped, filled);
    return line;
}

}  // namespace refocus
