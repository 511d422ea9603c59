#include "fit/confidence.h"

#include <ATen/Parallel.h>
#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "ops/morphology.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

torch::Tensor smoothstep01(const torch::Tensor& x) {
    auto c = x.clamp(0, 1);
    return c * c * (3 - 2 * c);
}

// A box mean over (2·radius + 1)² px, edges replicated: a map's seam made a ramp.
torch::Tensor feather(const torch::Tensor& m, int radius) {
    return box_filter(m, radius);
}

// The unexplained share from threshold lo (a number or a map): a smoothstep from lo to 2·lo,
// grown and feathered by 4 px. Not opened: a thin unexplained band (an occlusion edge under
// parallax, a misregistered edge) is where the atlas is wrong, and the shot is better there
// (docs/method.md).
torch::Tensor share_above(const torch::Tensor& resid, const torch::Tensor& lo) {
    return feather(max_filter(smoothstep01((resid - lo) / lo), 4), 4);
}

}  // namespace

torch::Tensor unexplained_share(const torch::Tensor& resid, double k, double min) {
    if (!resid.defined() || (resid < 0).any().item<bool>()) return {};
    torch::NoGradGuard g;
    const double lo = std::max(k * resid.median().item<double>(), min);
    return share_above(resid, torch::full({}, lo, resid.options()));
}

torch::Tensor unexplained_share_evidence(const torch::Tensor& resid, const torch::Tensor& change,
                                         double noise_levels, double change_share, double floor) {
    if (!resid.defined() || !change.defined() || (resid < 0).any().item<bool>()) return {};
    torch::NoGradGuard g;
    auto lo =
        (0.8 * std::max(noise_levels, 0.0) / 255.0 + floor + change_share * change.view_as(resid))
            .clamp_min(1e-4);
    return share_above(resid, lo);
}

torch::Tensor warp_frame_map(const torch::Tensor& m_s, const torch::Tensor& to_ref, int s, int t,
                             bool outside_zero) {
    torch::NoGradGuard g;
    const int64_t H = m_s.size(2), W = m_s.size(3);
    auto h = torch::matmul(torch::linalg_inv(to_ref[s]), to_ref[t]).to(torch::kFloat32);  // t → s
    auto ys = torch::arange(H, torch::kFloat32).view({H, 1}).expand({H, W});
    auto xs = torch::arange(W, torch::kFloat32).view({1, W}).expand({H, W});
    auto p = torch::stack({xs, ys, torch::ones_like(xs)}, -1).view({-1, 3});  // [HW,3]
    auto q = torch::matmul(p, h.t());
    auto w = q.narrow(1, 2, 1).clamp_min(1e-6);
    auto gx = (2 * q.narrow(1, 0, 1) / w + 1) / W - 1;
    auto gy = (2 * q.narrow(1, 1, 1) / w + 1) / H - 1;
    auto grid = torch::cat({gx, gy}, 1).view({1, H, W, 2});
    F::GridSampleFuncOptions::padding_mode_t pad = torch::kBorder;
    if (outside_zero) pad = torch::kZeros;
    return F::grid_sample(
        m_s, grid,
        F::GridSampleFuncOptions().mode(torch::kBilinear).padding_mode(pad).align_corners(false));
}

torch::Tensor temporal_unexplained(int t, int frames, int window, const torch::Tensor& to_ref,
                                   bool static_camera,
                                   const std::function<torch::Tensor(int)>& u_of) {
    torch::NoGradGuard g;
    auto own = u_of(t);
    if (!own.defined() || window <= 0) return own;
    // The frame's own share, raised toward its neighbours' mean (drawn into frame t): a frame
    // keeps its own fallback in full, and a region that falls back in the frames around it
    // fades in and out instead of switching on and off.
    torch::Tensor sum = own;
    int n = 1;
    for (int s = std::max(0, t - window); s <= std::min(frames - 1, t + window); ++s) {
        if (s == t) continue;
        auto m = u_of(s);
        if (!m.defined()) continue;
        if (!static_camera && to_ref.defined()) m = warp_frame_map(m, to_ref, s, t);
        sum = sum + m;
        ++n;
    }
    return torch::maximum(own, sum / n);
}

torch::Tensor sharpest_seen(int t, int frames, int max_frames, const torch::Tensor& to_ref,
                            bool static_camera, double unseen_px,
                            const std::function<torch::Tensor(int)>& radius_of) {
    return seen_radius(t, frames, max_frames, to_ref, static_camera, unseen_px, radius_of,
                       /*with_most=*/false)
        .least;
}

SeenRadius seen_radius(int t, int frames, int max_frames, const torch::Tensor& to_ref,
                       bool static_camera, double unseen_px,
                       const std::function<torch::Tensor(int)>& radius_of, bool with_most) {
    torch::NoGradGuard g;
    auto as_map = [](const torch::Tensor& r) {
        return r.view({1, 1, r.size(-2), r.size(-1)}).to(torch::kFloat32);
    };
    auto least = as_map(radius_of(t));
    torch::Tensor most = with_most ? least : torch::Tensor();
    const bool warp = !static_camera && to_ref.defined();
    // Every frame when they are few, else an even spread (the radius changes smoothly in time,
    // so a spread misses a focus hit by at most the change over its stride).
    const int spread = std::max(1, max_frames);
    const int stride = std::max(1, (frames + spread - 1) / spread);
    for (int s = t % stride; s < frames; s += stride) {
        if (s == t) continue;
        auto r = as_map(radius_of(s));
        if (warp) {
            // Drawn as (unseen − r) with zeros outside frame s: a pixel it did not see reads
            // unseen, which lowers no least; for the most, only pixels frame s saw count.
            auto far = warp_frame_map(unseen_px - r.clamp_max(unseen_px), to_ref, s, t,
                                      /*outside_zero=*/true);
            least = torch::minimum(least, unseen_px - far);
            if (!with_most) continue;
            auto seen = warp_frame_map(torch::ones_like(r), to_ref, s, t, /*outside_zero=*/true);
            most = torch::maximum(
                most, torch::where(seen > 0.999, unseen_px * seen - far, torch::zeros_like(r)));
        } else {
            least = torch::minimum(least, r);
            if (with_most) most = torch::maximum(most, r);
        }
    }
    return {least, most};
}

torch::Tensor seen_trust(const torch::Tensor& sharpest, double trust_px) {
    torch::NoGradGuard g;
    if (!(trust_px > 0)) return torch::ones_like(sharpest);
    return feather(1.0 - smoothstep01((sharpest - trust_px) / trust_px), 4);
}

torch::Tensor blur_reach_reference(const torch::Tensor& radius) {
    torch::NoGradGuard g;
    auto r = radius.view({1, 1, radius.size(-2), radius.size(-1)}).to(torch::kFloat32);
    // Cone dilation max_q (r(q) − |p − q|_∞): as many 3x3 steps as the widest radius.
    const int steps = std::min(64, static_cast<int>(std::ceil(r.max().item<double>())));
    auto reach = r;
    for (int i = 0; i < steps; ++i) reach = torch::maximum(reach, max_filter(reach, 1) - 1.0);
    return reach;
}

torch::Tensor blur_reach(const torch::Tensor& radius) {
    torch::NoGradGuard g;
    auto reach = radius.view({1, 1, radius.size(-2), radius.size(-1)})
                     .to(torch::kFloat32)
                     .contiguous()
                     .clone();
    const int steps = std::min(64, static_cast<int>(std::ceil(reach.max().item<double>())));
    if (steps <= 0 || !torch::isfinite(reach).all().item<bool>())
        return blur_reach_reference(radius);
    // The reference's steps fused in place: a 3-wide max along x into `rows`, then along y,
    // less 1, against the pixel itself. Max is exact and r − 1 is the same float subtraction, so
    // the result is the reference's bit for bit (test_confidence), without four frame-sized
    // allocations a step (at 1080p, 0.6 s of an export frame).
    const int64_t H = reach.size(2), W = reach.size(3);
    auto rows_t = torch::empty_like(reach);
    float* a = reach.data_ptr<float>();
    float* rows = rows_t.data_ptr<float>();
    for (int i = 0; i < steps; ++i) {
        at::parallel_for(0, H, 16, [&](int64_t y0, int64_t y1) {
            for (int64_t y = y0; y < y1; ++y) {
                const float* s = a + y * W;
                float* d = rows + y * W;
                for (int64_t x = 0; x < W; ++x) {
                    float m = s[x];
                    if (x > 0) m = std::max(m, s[x - 1]);
                    if (x + 1 < W) m = std::max(m, s[x + 1]);
                    d[x] = m;
                }
            }
        });
        // Row y of the result reads rows y − 1 … y + 1 of `rows` only, so it is written in place.
        at::parallel_for(0, H, 16, [&](int64_t y0, int64_t y1) {
            for (int64_t y = y0; y < y1; ++y) {
                const float* up = rows + (y > 0 ? y - 1 : y) * W;
                const float* mid = rows + y * W;
                const float* dn = rows + (y + 1 < H ? y + 1 : y) * W;
                float* d = a + y * W;
                for (int64_t x = 0; x < W; ++x) {
                    const float m = std::max(std::max(up[x], mid[x]), dn[x]) - 1.0f;
                    d[x] = std::max(d[x], m);
                }
            }
        });
    }
    return reach;
}

double residual_excess(double rms, double noise_levels) {
    const double noise = 0.8 * std::max(noise_levels, 0.0);
    return std::sqrt(std::max(0.0, rms * rms - noise * noise));
}

double explained_trust(double rms, double noise_levels, double lo) {
    if (!(lo > 0) || !std::isfinite(rms)) return 0.0;
    const double x = std::clamp((residual_excess(rms, noise_levels) - lo) / (0.4 * lo), 0.0, 1.0);
    return 1.0 - x * x * (3 - 2 * x);
}

torch::Tensor blur_need(const torch::Tensor& reach, double focus_px) {
    torch::NoGradGuard g;
    if (!(focus_px > 0)) return torch::ones_like(reach);
    return smoothstep01((reach - focus_px) / focus_px);
}

torch::Tensor sharper_view(const torch::Tensor& reach, const torch::Tensor& sharpest,
                           double gain_px) {
    torch::NoGradGuard g;
    if (!(gain_px > 0)) return torch::ones_like(reach);
    return feather(smoothstep01((reach - sharpest.view_as(reach) - gain_px) / gain_px), 4);
}

torch::Tensor sharper_view(const torch::Tensor& reach, const torch::Tensor& sharpest,
                           const torch::Tensor& range, double gain_px, double moved_gain_px,
                           double moved_px) {
    torch::NoGradGuard g;
    if (!(moved_px > 0) || !range.defined()) return sharper_view(reach, sharpest, gain_px);
    if (!(gain_px > 0)) return torch::ones_like(reach);
    auto moved = smoothstep01((range.view_as(reach) - 0.6 * moved_px) / (0.4 * moved_px));
    // At least a hundredth of a px: a threshold of 0 is a step at the first sharper view.
    auto gain = (gain_px + (moved_gain_px - gain_px) * moved).clamp_min(0.01);
    return feather(smoothstep01((reach - sharpest.view_as(reach) - gain) / gain), 4);
}

double focus_travel(int frames, const std::function<torch::Tensor(int)>& radius_of,
                    const std::function<torch::Tensor(int)>& region_of) {
    const auto span = focus_span(frames, radius_of, region_of);
    return span.seen ? span.most - span.least : 0.0;
}

FocusSpan focus_span(int frames, const std::function<torch::Tensor(int)>& radius_of,
                     const std::function<torch::Tensor(int)>& region_of) {
    torch::NoGradGuard g;
    double lo = 1e30, hi = -1e30;
    // A median needs no more than ~65 000 samples: larger frames are read on a grid (1080p
    // every 5th pixel), so a long clip's first export frame does not wait on full-size sorts.
    auto grid = [](const torch::Tensor& x) {
        const int64_t step =
            std::max<int64_t>(1, int64_t(std::sqrt(double(x.size(-2) * x.size(-1)) / 65536.0)));
        return step > 1 ? x.slice(-2, 0, x.size(-2), step).slice(-1, 0, x.size(-1), step) : x;
    };
    for (int s = 0; s < frames; ++s) {
        auto r = grid(radius_of(s)).to(torch::kFloat32).reshape({-1});
        if (auto m = region_of ? region_of(s) : torch::Tensor(); m.defined()) {
            auto in = grid(m).to(torch::kFloat32).reshape({-1}) >= 0.5;
            if (in.sum().item<int64_t>() < std::max<int64_t>(1, r.numel() / 100)) continue;
            r = r.masked_select(in);
        }
        const double med = r.median().item<double>();
        lo = std::min(lo, med), hi = std::max(hi, med);
    }
    if (!(hi >= lo)) return {};
    return {lo, hi, true};
}

torch::Tensor range_by_travel(const torch::Tensor& range, double travel, double moved_px,
                              double travel_px) {
    torch::NoGradGuard g;
    if (!range.defined() || !(travel_px > 0) || !(moved_px > 0)) return range;
    const double u = std::clamp((travel - 0.75 * travel_px) / (0.25 * travel_px), 0.0, 1.0);
    const double s = u * u * (3 - 2 * u);
    // Half the travel, never above moved_px itself: a long rack keeps the absolute test.
    const double moved_eff = (1 - s) * moved_px + s * std::min(moved_px, 0.5 * travel);
    return moved_eff < moved_px ? range * (moved_px / moved_eff) : range;
}

torch::Tensor gaussian_blur(const torch::Tensor& x, double sigma) {
    const int r = std::max(1, int(std::ceil(3 * sigma)));
    auto k = torch::arange(-r, r + 1, x.options());
    k = torch::exp(-k * k / (2 * sigma * sigma));
    k = k / k.sum();
    const int64_t c = x.size(1);
    auto kx = k.view({1, 1, 1, -1}).repeat({c, 1, 1, 1});
    auto ky = k.view({1, 1, -1, 1}).repeat({c, 1, 1, 1});
    auto y = F::pad(x, F::PadFuncOptions({r, r, 0, 0}).mode(torch::kReplicate));
    y = F::conv2d(y, kx, F::Conv2dFuncOptions().groups(c));
    y = F::pad(y, F::PadFuncOptions({0, 0, r, r}).mode(torch::kReplicate));
    return F::conv2d(y, ky, F::Conv2dFuncOptions().groups(c));
}

torch::Tensor low_frequency_lock(const torch::Tensor& model, const torch::Tensor& input,
                                 double sigma) {
    torch::NoGradGuard g;
    return gaussian_blur(input - model, sigma);
}

}  // namespace refocus
