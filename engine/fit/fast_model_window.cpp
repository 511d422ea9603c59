// The fast model over windows of its frames (the fit's crop step, docs/method.md, Crops): the
// atlas coordinates of a window's pixels, the atlas boxes they read (composed, prefiltered for a
// subject seen smaller than in its atlas, sampled), and the priors restricted to them.
#include <torch/torch.h>

#include <algorithm>
#include <cmath>

#include "fit/crops.h"
#include "fit/fast_model.h"
#include "fit/losses.h"
#include "model/atlas_geometry.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

// lo..hi (inclusive) within 0..n − 1, at least two long where n allows (a difference needs two).
std::pair<int64_t, int64_t> span_of(int64_t lo, int64_t hi, int64_t n) {
    lo = std::clamp<int64_t>(lo, 0, std::max<int64_t>(0, n - 2));
    hi = std::clamp<int64_t>(hi, std::min(lo + 1, n - 1), n - 1);
    return {lo, hi};
}

// Cells lo..hi (inclusive) of a grid of n cells that a bilinear upsample to L px reads over
// pixels [from, from + len), grown by one cell a side (a difference needs its neighbour).
// With `corners` pixel i reads cell i·(n − 1)/(L − 1), without (i + ½)·n/L − ½.
std::pair<int64_t, int64_t> cells_read(int64_t from, int64_t len, int64_t L, int64_t n,
                                       bool corners) {
    auto at = [&](int64_t i) {
        const double p = std::clamp<double>(double(i), 0.0, double(L - 1));
        return corners ? (L > 1 ? p * double(n - 1) / double(L - 1) : 0.0)
                       : (p + 0.5) * double(n) / double(L) - 0.5;
    };
    const int64_t lo = int64_t(std::floor(at(from))) - 1;
    const int64_t hi = int64_t(std::floor(at(from + len - 1))) + 2;
    return span_of(lo, hi, n);
}

// The footprint prefilter's 2r + 1 taps, normalised: a Gaussian of σ² = (s² − 1)/12 texels², or
// three exact taps (v/2, 1 − v, v/2) under ½ texel² (prefilter_reach says why).
torch::Tensor footprint_taps(double s, int64_t r, const torch::TensorOptions& options) {
    const double var = (s * s - 1.0) / 12.0;
    auto x = torch::arange(-r, r + 1, options);
    auto k = var < 0.5 ? torch::tensor({var / 2, 1 - var, var / 2}, options)
                       : torch::exp(-x * x / (2 * var));
    return k / k.sum();
}

}  // namespace

int64_t prefilter_reach(double s) {
    const double var = (s * s - 1.0) / 12.0;
    if (!(var >= 0.01)) return 0;  // σ < 0.1 texel (or s ≤ 1): nothing to remove
    // Under half a texel² a sampled Gaussian falls short of its variance (σ² 0.10: 0.016), so
    // three taps (v/2, 1 − v, v/2) carry it exactly; past it the sampled Gaussian is within 1%.
    return var < 0.5 ? 1 : static_cast<int64_t>(std::ceil(3 * std::sqrt(var)));
}

torch::Tensor prefilter_for_footprint(const torch::Tensor& image, double s) {
    // A frame pixel integrates the scene over its footprint, s × s texels where a layer is seen
    // s times smaller than in its atlas (a subject walking away: synth walkout's last frames,
    // s ≈ 2.5). Sampling the atlas there without prefiltering aliases its fine texture (the
    // shirt's stripes). A texel already holds its own box (variance 1/12 a side), so the
    // footprint's box (s²/12) is met by a Gaussian of the rest: σ² = (s² − 1)/12 texels².
    const int64_t r = prefilter_reach(s);
    if (r == 0) return image;
    if (image.scalar_type() != torch::kFloat32) return prefilter_for_footprint_reference(image, s);
    const auto k = footprint_taps(s, r, image.options()).contiguous();
    std::vector<float> taps(k.data_ptr<float>(), k.data_ptr<float>() + k.numel());
    // Shifted slices, one multiply-add a tap: LibTorch's depthwise conv2d takes a slow path on
    // the CPU (3 s a frame for a 1080p subject atlas and 3 taps, against 0.1 s).
    auto along = [&](const torch::Tensor& padded, int64_t dim) {
        const int64_t n = padded.size(dim) - 2 * r;
        auto out = padded.narrow(dim, 0, n) * taps[0];
        for (int64_t i = 1; i <= 2 * r; ++i) out.add_(padded.narrow(dim, i, n), taps[size_t(i)]);
        return out;
    };
    auto img = F::pad(image, F::PadFuncOptions({r, r, r, r}).mode(torch::kReplicate));
    return along(along(img, 3), 2);
}

torch::Tensor prefilter_for_footprint_reference(const torch::Tensor& image, double s) {
    const int64_t r = prefilter_reach(s);
    if (r == 0) return image;
    const int64_t C = image.size(1);
    const auto k = footprint_taps(s, r, image.options());
    auto img = F::pad(image, F::PadFuncOptions({r, r, r, r}).mode(torch::kReplicate));
    img = F::conv2d(img, k.view({1, 1, 1, -1}).expand({C, 1, 1, 2 * r + 1}),
                    F::Conv2dFuncOptions().groups(C));
    return F::conv2d(img, k.view({1, 1, -1, 1}).expand({C, 1, 2 * r + 1, 1}),
                     F::Conv2dFuncOptions().groups(C));
}

double FastModel::footprint(int64_t t) const {
    // Relative to the atlas's own resolution: a 2x atlas is not a minification (its texels are
    // half a frame pixel by design).
    auto J = m_fg.to_atlas[t].narrow(0, 0, 2).narrow(1, 0, 2).to(torch::kFloat64);
    return std::sqrt(std::abs(torch::det(J).item<double>())) / m_fg.scale;
}

torch::Tensor FastModel::minified(const torch::Tensor& fg,
                                  const std::vector<int64_t>& frames) const {
    const int64_t B = frames.size();
    const auto img = fg.view({1, 3, m_fg.height, m_fg.width});
    std::vector<torch::Tensor> per;
    bool any = false;
    for (int64_t b = 0; b < B; ++b) {
        auto f = prefilter_for_footprint(img, footprint(frames[b]));
        any = any || !f.is_same(img);
        per.push_back(f[0]);
    }
    return any ? torch::stack(per) : img.expand({B, 3, m_fg.height, m_fg.width});
}

bool FastModel::covers_frames(const Layers& layers) const {
    const int64_t H = m_data.height, W = m_data.width;
    const int64_t pad = (layers.sharp.size(3) - W) / 2;
    auto at_pad = [&](const std::vector<int64_t>& v) {
        return std::all_of(v.begin(), v.end(), [&](int64_t c) { return c == -pad; });
    };
    return at_pad(layers.x0) && at_pad(layers.y0) && layers.sharp.size(2) == H + 2 * pad &&
           layers.sharp.size(3) == W + 2 * pad;
}

torch::Tensor FastModel::map_coords_window(const Atlas& a, const std::vector<int64_t>& frames,
                                           const std::vector<int64_t>& x0,
                                           const std::vector<int64_t>& y0, int64_t h,
                                           int64_t w) const {
    const int64_t B = frames.size();
    auto idx = torch::tensor(frames, torch::kLong);
    auto p = torch::matmul(a.to_atlas.index_select(0, idx), window_pixels(x0, y0, h, w));
    auto px = (p.narrow(1, 0, 2) / p.narrow(1, 2, 1)).view({B, 2, h, w});
    if (a.learn_warp || a.warp.requires_grad())  // the residual warp is held constant past the edge
        px = px + a.scale * upsample_window(a.warp.index_select(0, idx), m_data.height,
                                            m_data.width, x0, y0, h, w, true);
    return add_parallax(a, idx, px).permute({0, 2, 3, 1});
}

torch::Tensor FastModel::boot_weight(const torch::Tensor& subject_r) {
    // The masks are trusted as much as the subject is sharp there (1 at r = 0, 0.2 at 4 px,
    // 0.07 at 7 px), in absolute terms: automatic masks of a blurred subject are blobs its blur
    // widens, and a subject never in focus earns no trust by being the clip's sharpest
    // (docs/method.md, Model). Made for the step's frames: a clip array of it is minutes of
    // writing on a long clip.
    return 1.0 / (1.0 + (subject_r / 2.0).pow(2));
}

torch::Tensor FastModel::bootstrap_l1(const Layers& layers,
                                      const std::vector<int64_t>& frames) const {
    const int64_t H = m_data.height, W = m_data.width, h = layers.alpha.size(2),
                  w = layers.alpha.size(3);
    const int64_t pad = (w - W) / 2;
    auto idx = torch::tensor(frames, torch::kLong);
    if (covers_frames(layers)) {  // whole frames (render_padded)
        auto alpha = layers.alpha.narrow(2, pad, H).narrow(3, pad, W);
        return ((alpha - m_data.mask.index_select(0, idx)).abs() *
                boot_weight(m_data.layer_radius(true).index_select(0, idx).unsqueeze(1)))
            .mean();
    }
    // Windows (render_window): each frame's part inside the frame, averaged over all of them.
    torch::Tensor sum = torch::zeros({});
    int64_t n = 0;
    for (size_t b = 0; b < frames.size(); ++b) {
        const int64_t fx0 = std::max<int64_t>(layers.x0[b], 0),
                      fx1 = std::min<int64_t>(layers.x0[b] + w, W),
                      fy0 = std::max<int64_t>(layers.y0[b], 0),
                      fy1 = std::min<int64_t>(layers.y0[b] + h, H);
        if (fx1 <= fx0 || fy1 <= fy0) continue;
        auto in_frame = [&](const torch::Tensor& x) {  // [C,H,W] of the frame → its part
            return x.narrow(1, fy0, fy1 - fy0).narrow(2, fx0, fx1 - fx0);
        };
        auto a = layers.alpha[b]
                     .narrow(1, fy0 - layers.y0[b], fy1 - fy0)
                     .narrow(2, fx0 - layers.x0[b], fx1 - fx0);
        const int64_t t = frames[b];
        const auto r = in_frame(m_data.layer_radius(true)[t].unsqueeze(0));
        sum = sum + ((a - in_frame(m_data.mask[t])).abs() * boot_weight(r)).sum();
        n += (fx1 - fx0) * (fy1 - fy0);
    }
    return sum / double(std::max<int64_t>(n, 1));
}

torch::Tensor FastModel::warp_smoothness(const torch::Tensor& w) {
    auto dx = w.narrow(3, 1, w.size(3) - 1) - w.narrow(3, 0, w.size(3) - 1);
    auto dy = w.narrow(2, 1, w.size(2) - 1) - w.narrow(2, 0, w.size(2) - 1);
    return dx.pow(2).mean() + dy.pow(2).mean() + 1e-3 * w.pow(2).mean();
}

FastModel::AtlasWindow FastModel::window_box(const Atlas& a, const torch::Tensor& px,
                                             int64_t grow) const {
    // Bicubic taps at x read texels ⌊x⌋ − 1 … ⌊x⌋ + 2; window_tv's box (⌊x⌋ − 2 … ⌊x⌋ + 3, one
    // more for its differences) plus a texel, as it derives x from the grid by another rounding.
    auto p = px.detach().reshape({-1, 2});
    auto lo = std::get<0>(p.min(0)), hi = std::get<0>(p.max(0));
    auto span = [&](int k, int64_t n) {
        return span_of(int64_t(std::floor(lo[k].item<double>())) - 3 - grow,
                       int64_t(std::floor(hi[k].item<double>())) + 4 + grow, n);
    };
    const auto [x0, x1] = span(0, a.width);
    const auto [y0, y1] = span(1, a.height);
    AtlasWindow win;
    win.x0 = x0, win.y0 = y0, win.w = x1 - x0 + 1, win.h = y1 - y0 + 1;
    return win;
}

std::vector<FastModel::AtlasWindow> FastModel::paying_windows(const Atlas& a,
                                                              const torch::Tensor& px,
                                                              const std::vector<int64_t>& frames,
                                                              bool minify) const {
    // A deblurring path's filter reaches past any box: its atlas is composed whole.
    if (a.deblur.defined()) return {};
    std::vector<AtlasWindow> wins;
    int64_t texels = 0;
    for (size_t b = 0; b < frames.size(); ++b) {
        const double s = minify ? footprint(frames[b]) : 1.0;
        // The prefilter's reach too: its replicated edge is then never read but at the atlas's.
        wins.push_back(window_box(a, px[b], prefilter_reach(s)));
        wins.back().footprint = s;
        texels += wins.back().w * wins.back().h;
    }
    if (!(double(texels) < m_opts.window_share * double(a.width * a.height))) return {};
    return wins;
}

void FastModel::compose_window(const Atlas& a, AtlasWindow& win) const {
    // Each level as compose() upsamples it (bilinear, align_corners false), at the box's
    // texels only (upsample_window: the same weights through grid_sample).
    win.composed = torch::Tensor();
    for (const auto& l : a.levels) {
        auto up =
            l.size(2) == a.height && l.size(3) == a.width
                ? l.narrow(2, win.y0, win.h).narrow(3, win.x0, win.w)
                : upsample_window(l, a.height, a.width, {win.x0}, {win.y0}, win.h, win.w, false);
        win.composed = win.composed.defined() ? win.composed + up : up;
    }
}

torch::Tensor FastModel::sample_windows(const Atlas& a, const torch::Tensor& px,
                                        std::vector<AtlasWindow> wins,
                                        std::vector<AtlasWindow>* keep) const {
    std::vector<torch::Tensor> out;
    for (size_t b = 0; b < wins.size(); ++b) {
        AtlasWindow& win = wins[b];
        compose_window(a, win);
        auto img = prefilter_for_footprint(win.composed, win.footprint);
        auto grid = (px[b].unsqueeze(0) - torch::tensor({float(win.x0), float(win.y0)}) + 0.5) *
                        torch::tensor({2.0f / float(win.w), 2.0f / float(win.h)}) -
                    1.0;
        out.push_back(sample_bicubic(img, grid)[0]);
    }
    if (keep) *keep = std::move(wins);
    return torch::stack(out);
}

torch::Tensor FastModel::window_tv(const Atlas& a, const std::vector<AtlasWindow>& wins,
                                   const torch::Tensor& composed, const torch::Tensor& uv) const {
    // Each window's box in the atlas: the texels its bicubic taps read (uv in [-1, 1] spans
    // the atlas, texel i centred at (2i + 1)/size − 1), grown by one for the differences.
    const int64_t B = uv.size(0);
    torch::Tensor sum = torch::zeros({}), whole = composed;
    for (int64_t b = 0; b < B; ++b) {
        auto px = (uv[b].detach().reshape({-1, 2}) + 1.0) *
                      torch::tensor({0.5f * float(a.width), 0.5f * float(a.height)}) -
                  0.5;
        auto lo = std::get<0>(px.min(0)), hi = std::get<0>(px.max(0));
        auto box = [&](int k, int64_t n) {
            const auto [l, h] = span_of(int64_t(std::floor(lo[k].item<double>())) - 2,
                                        int64_t(std::floor(hi[k].item<double>())) + 3, n);
            return std::make_pair(l, h - l + 1);
        };
        const auto [x0, w] = box(0, a.width);
        const auto [y0, h] = box(1, a.height);
        auto weight =
            a.tv_weight.defined() ? a.tv_weight.narrow(2, y0, h).narrow(3, x0, w) : torch::Tensor();
        torch::Tensor texels;
        if (size_t(b) < wins.size() && wins[b].x0 <= x0 && wins[b].y0 <= y0 &&
            x0 + w <= wins[b].x0 + wins[b].w && y0 + h <= wins[b].y0 + wins[b].h) {
            texels = wins[b].composed.narrow(2, y0 - wins[b].y0, h).narrow(3, x0 - wins[b].x0, w);
        } else {  // the reference path: the atlas composed whole
            if (!whole.defined()) whole = compose(a);
            texels = whole.narrow(2, y0, h).narrow(3, x0, w);
        }
        sum = sum + tv_l1(texels, weight);
    }
    return sum / double(B);
}

torch::Tensor FastModel::window_warp(const Atlas& a, const Layers& layers,
                                     const std::vector<int64_t>& frames) const {
    const int64_t gh = a.warp.size(2), gw = a.warp.size(3);
    const int64_t h = layers.sharp.size(2), w = layers.sharp.size(3);
    torch::Tensor sum = torch::zeros({});
    for (size_t b = 0; b < frames.size(); ++b) {
        const auto ry = cells_read(layers.y0[b], h, m_data.height, gh, true);
        const auto rx = cells_read(layers.x0[b], w, m_data.width, gw, true);
        auto cells = a.warp[frames[b]]
                         .narrow(1, ry.first, ry.second - ry.first + 1)
                         .narrow(2, rx.first, rx.second - rx.first + 1)
                         .unsqueeze(0);
        sum = sum + warp_smoothness(cells);
    }
    return sum / double(frames.size());
}

torch::Tensor FastModel::window_alpha_residual(const Layers& layers,
                                               const std::vector<int64_t>& frames) const {
    const int64_t gh = m_alpha_logit.size(2), gw = m_alpha_logit.size(3);
    const int64_t h = layers.sharp.size(2), w = layers.sharp.size(3);
    torch::Tensor sum = torch::zeros({});
    for (size_t b = 0; b < frames.size(); ++b) {
        const auto ry = cells_read(layers.y0[b], h, m_data.height, gh, false);
        const auto rx = cells_read(layers.x0[b], w, m_data.width, gw, false);
        sum = sum + m_alpha_logit[frames[b]]
                        .narrow(1, ry.first, ry.second - ry.first + 1)
                        .narrow(2, rx.first, rx.second - rx.first + 1)
                        .abs()
                        .mean();
    }
    return sum / double(frames.size());
}

torch::Tensor FastModel::compose_still(const Atlas& a, StillAtlas& memo) const {
    std::vector<torch::Tensor> parts(a.levels.begin(), a.levels.end());
    parts.push_back(a.deblur);
    parts.push_back(a.deblur_kernel);
    std::vector<int64_t> versions;
    for (const auto& t : parts) versions.push_back(t.defined() ? int64_t(t._version()) : -1);
    bool same =
        memo.composed.defined() && parts.size() == memo.parts.size() && versions == memo.versions;
    for (size_t i = 0; same && i < parts.size(); ++i) same = parts[i].is_same(memo.parts[i]);
    if (!same) {
        memo.composed = compose(a);
        memo.parts = std::move(parts);
        memo.versions = std::move(versions);
    }
    return memo.composed;
}

}  // namespace refocus
