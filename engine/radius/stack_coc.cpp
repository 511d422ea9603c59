#include "radius/stack_coc.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>

#include "model/atlas_geometry.h"
#include "radius/spectral_blur.h"
#include "io/tensor_image.h"
#include "ops/lens_blur.h"
#include "ops/morphology.h"
#include "ops/uniform_blur.h"
#include "prepare/coc.h"
#include "radius/stack_costs.h"
#include "radius/stack_floor.h"
#include "util/threads.h"
#include "util/timing.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

// Where a [N,1,H,W] 0/1 map is 1 over the whole (2r+1)² window around a pixel.
torch::Tensor erode(const torch::Tensor& valid, int r) {
    return min_filter(valid, r);
}

// Push-pull fill: v [N,1,H,W] kept where w (0/1) is 1, the rest filled from the nearest kept
// values at the coarsest scale that reaches them, blended up the pyramid.
torch::Tensor fill_from(const torch::Tensor& v, const torch::Tensor& w) {
    if ((w > 0).all().item<bool>()) return v;
    if (std::min(v.size(2), v.size(3)) <= 1) {  // coarsest: holes take the kept values' mean
        auto mean = (v * w).sum({2, 3}, true) / w.sum({2, 3}, true).clamp_min(1e-12);
        return w * v + (1 - w) * mean;
    }
    auto opts = F::AvgPool2dFuncOptions(2).stride(2).ceil_mode(true);
    auto wd = F::avg_pool2d(w, opts);
    auto vd = F::avg_pool2d(v * w, opts) / wd.clamp_min(1e-12);
    auto coarse = fill_from(vd, (wd > 0).to(v.scalar_type()));
    auto up = F::interpolate(coarse, F::InterpolateFuncOptions()
                                         .size(std::vector<int64_t>{v.size(2), v.size(3)})
                                         .mode(torch::kBilinear)
                                         .align_corners(false));
    return w * v + (1 - w) * up;
}

// The layer's frames on a canvas in reference coordinates and their all-in-focus composite.
struct LayerComposite {
    int64_t Hc = 0, Wc = 0;
    torch::Tensor to_canvas;  // [T,3,3] float64 frame → canvas
    std::vector<torch::Tensor>
        reg_valid;           // per frame [1,Hc,Wc]: 1 where the frame covers the canvas
    torch::Tensor aif;       // [3,Hc,Wc] all-in-focus composite
    torch::Tensor covered;   // [1,1,Hc,Wc] where the composite has a view
    torch::Tensor own_seen;  // [Hc,Wc] where the composite is the layer's own
};

// 1. Every frame on a canvas that covers all of them (canvas pixel p reads frame t at
//    to_canvas_t⁻¹ p): on a canvas of the reference frame's size, read with border padding,
//    content entering a pan later would take smeared border pixels as its "sharpest view".
// 2. All-in-focus: local contrast (box-filtered squared Laplacian of luma) picks, softly, the
//    sharpest frame at each pixel among the views whose contrast window lies inside their frame.
// `canvas`: the canvas's box in reference coordinates (none: the frames' mapped box).
LayerComposite layer_composite(const FitData& d, const torch::Tensor& to_ref_in,
                               const torch::Tensor& region, const StackCocOptions& o,
                               const AtlasBox* canvas) {
    ScopedTiming timing("radius: the composite");
    const int64_t T = d.frames, H = d.height, W = d.width;
    LayerComposite c;
    const AtlasBox box_ref = canvas ? *canvas : mapped_frames_box(to_ref_in, H, W);
    c.Hc = box_ref.height;
    c.Wc = box_ref.width;
    const int64_t Hc = c.Hc, Wc = c.Wc;
    c.to_canvas = torch::matmul(translation(-box_ref.origin_x, -box_ref.origin_y).unsqueeze(0),
                                to_ref_in.to(torch::kFloat64));
    // Two passes over the frames, one frame in memory at a time (a long clip's views would be
    // GBs on the canvas): the sharpest contrast each canvas pixel has in any view, then each
    // view's weight against it, accumulated.
    auto ones = torch::ones({1, 1, H, W});
    const auto lap_kernel =
        torch::tensor({0.f, 1.f, 0.f, 1.f, -4.f, 1.f, 0.f, 1.f, 0.f}).view({1, 1, 3, 3});
    struct View {
        torch::Tensor reg, valid, contrast, own;  // [1,3,Hc,Wc], [1,1,Hc,Wc] x3
    };
    auto view = [&](int64_t t, bool keep_valid) {
        View v;
        auto inv = torch::inverse(c.to_canvas[t]);
        v.reg = warp_to_canvas(d.input[t].unsqueeze(0), inv, Hc, Wc);
        auto reg_valid = (warp_to_canvas(ones, inv, Hc, Wc, true)[0] > 0.999).to(torch::kFloat32);
        if (keep_valid) c.reg_valid[t] = reg_valid;
        auto luma =
            (0.299 * v.reg.select(1, 0) + 0.587 * v.reg.select(1, 1) + 0.114 * v.reg.select(1, 2))
                .unsqueeze(1);
        auto lap = F::conv2d(F::pad(luma, F::PadFuncOptions({1, 1, 1, 1}).mode(torch::kReplicate)),
                             lap_kernel);
        v.valid = erode(reg_valid.unsqueeze(0), o.contrast_window + 1);
        v.contrast = box_filter(lap.pow(2), o.contrast_window) * v.valid;
        if (region.defined())
            v.own = (warp_to_canvas(region[t].unsqueeze(0), inv, Hc, Wc, true).clamp(0, 1) > 0.5)
                        .to(torch::kFloat32);
        return v;
    };
    // Each pass over the frames in two interleaved parts (t even, t odd), one a core
    // (for_each_in_parts): the same sums on any machine.
    constexpr int kParts = 2;
    c.reg_valid.resize(T);
    struct Part {
        torch::Tensor cmax, comax, wsum, acc, wsum_o, acc_o;
    };
    Part parts[kParts];
    auto each_part = [&](const std::function<void(int64_t t, Part&)>& fn) {
        for_each_in_parts(T, kParts, [&](int64_t t, int p) { fn(t, parts[p]); });
    };
    for (Part& p : parts) p.cmax = torch::zeros({1, 1, Hc, Wc}), p.comax = p.cmax.clone();
    each_part([&](int64_t t, Part& p) {
        const View v = view(t, true);
        p.cmax = torch::maximum(p.cmax, v.contrast);
        if (region.defined()) p.comax = torch::maximum(p.comax, v.contrast * v.own);
    });
    auto cmax = parts[0].cmax, comax = parts[0].comax;
    for (int64_t k = 1; k < kParts; ++k)
        cmax = torch::maximum(cmax, parts[k].cmax), comax = torch::maximum(comax, parts[k].comax);
    for (Part& p : parts) {
        p.wsum = torch::zeros({1, 1, Hc, Wc}), p.acc = torch::zeros({1, 3, Hc, Wc});
        p.wsum_o = torch::zeros({1, 1, Hc, Wc}), p.acc_o = torch::zeros({1, 3, Hc, Wc});
    }
    each_part([&](int64_t t, Part& p) {
        const View v = view(t, false);
        auto w = (v.contrast / cmax.clamp_min(1e-12)).pow(8) * v.valid;
        p.wsum += w;
        p.acc += v.reg * w;
        if (region.defined()) {
            // The layer's own views first, weighed against the sharpest of them (against every
            // view's sharpest, a wall point seen blurred after a sharp subject stood over it
            // would count as never seen and keep no floor); where the layer is never seen,
            // every view.
            auto wo = (v.contrast * v.own / comax.clamp_min(1e-12)).pow(8) * v.valid * v.own;
            p.wsum_o += wo;
            p.acc_o += v.reg * wo;
        }
    });
    auto wsum = parts[0].wsum, acc = parts[0].acc, wsum_o = parts[0].wsum_o, acc_o = parts[0].acc_o;
    for (int64_t k = 1; k < kParts; ++k) {
        wsum = wsum + parts[k].wsum, acc = acc + parts[k].acc;
        wsum_o = wsum_o + parts[k].wsum_o, acc_o = acc_o + parts[k].acc_o;
    }
    c.own_seen = ((region.defined() ? wsum_o : wsum)[0][0] > 1e-6).to(torch::kFloat32);
    if (region.defined()) {
        auto use_own = wsum_o > 1e-6;
        wsum = torch::where(use_own, wsum_o, wsum);
        acc = torch::where(use_own, acc_o, acc);
    }
    c.aif = (acc / wsum.clamp_min(1e-12))[0];        // [3,Hc,Wc]
    c.covered = (wsum > 1e-12).to(torch::kFloat32);  // [1,1,Hc,Wc]
    return c;
}

// The composite warped onto a frame, its cover there, and its blur at each radius. Frames whose
// warp equals the frame before's to the bit share them, kept while they fit in kMaxBytes: on the
// plaza clip (docs/benchmarks.md, Speed) 34 of the 54 views measured, blurs and costs 5.5 -> 3.8 s.
struct CompositeBlurs {
    static constexpr int64_t kMaxBytes = int64_t(512) << 20;
    torch::Tensor key;  // the frame → canvas matrix the blurs were made for
    torch::Tensor aif_t, seen, spectrum;
    std::vector<torch::Tensor> blurs;
    bool keep = false;

    void to_frame(const LayerComposite& c, int64_t t, int64_t H, int64_t W,
                  const UniformBlurBank& bank, const StackCocOptions& o) {
        if (key.defined() && torch::equal(key, c.to_canvas[t])) return;
        key = c.to_canvas[t].clone();
        aif_t = warp_to_canvas(c.aif.unsqueeze(0), key, H, W)[0].contiguous();
        // Pixels whose matching window reads canvas the composite does not cover are not
        // measured.
        seen = erode(warp_to_canvas(c.covered, key, H, W, true).gt(0.999).to(torch::kFloat32),
                     o.window)[0][0];
        spectrum = o.direct_blur ? torch::Tensor() : bank.spectrum(aif_t);
        blurs.clear();
        keep = int64_t(bank.radii().size()) * aif_t.numel() * 4 <= kMaxBytes;
    }
    torch::Tensor blur(size_t k, const UniformBlurBank& bank, const LensBlurParams& bp,
                       const StackCocOptions& o) {
        if (k < blurs.size()) return blurs[k];
        const double rk = bank.radii()[k];
        const int64_t H = aif_t.size(1), W = aif_t.size(2);
        auto b = rk < bp.min_radius ? aif_t
                 : o.direct_blur    ? lens_blur(aif_t, torch::full({H, W}, float(rk)), bp)
                                    : bank.blur(spectrum, k);
        if (keep && k == blurs.size()) blurs.push_back(b);
        return b;
    }
};

// 3. Frame t's radius relative to the composite: the blur of the composite that matches the
//    frame best, locally; 4. spread from where the match is measured into flat regions. [H,W]
torch::Tensor relative_radius(const FitData& d, const LayerComposite& c,
                              const torch::Tensor& region, int64_t t, const UniformBlurBank& bank,
                              CompositeBlurs& blurs, const StackCocOptions& o) {
    const int64_t H = d.height, W = d.width;
    // A frame without a pixel of the layer has no evidence of blur anywhere: 0, as the spread
    // below gives it (a subject out of the frame, or lost by its masks).
    if (region.defined() && !(region[t][0] > 0.5).any().item<bool>()) return torch::zeros({H, W});
    const int64_t K = bank.radii().size();
    // The windowed cost of each radius, one map at a time: only its running least and largest,
    // the argmin and the costs beside it (for the parabola) are kept, not K frame-sized maps.
    StageClock clock;
    clock.next("radius: blurs and costs");
    blurs.to_frame(c, t, H, W, bank, o);
    const torch::Tensor& seen = blurs.seen;
    RunningArgmin run;
    for (int64_t k = 0; k < K; ++k)
        run.add(box_filter(squared_difference(blurs.blur(k, bank, d.blur, o), d.input[t]),
                           o.window)[0][0],
                k);
    const torch::Tensor &cmin = run.cmin, &cmax = run.cmax, &best = run.best, &c0 = run.c0,
                        &c1 = run.c1, &c2 = run.c2;
    clock.next("radius: argmin");
    // Sub-step refinement: parabola through the neighbours of the minimum.
    auto denom = (c0 - 2 * c1 + c2);
    auto off = torch::where(denom > 1e-12, 0.5 * (c0 - c2) / denom.clamp_min(1e-12),
                            torch::zeros_like(denom))
                   .clamp(-0.5, 0.5);
    auto interior = (best >= 1) & (best <= K - 2);
    auto r = best.to(torch::kFloat32) * o.rstep +
             torch::where(interior, off, torch::zeros_like(off)) * o.rstep;
    auto conf = (cmax - cmin) / (float(2 * o.window + 1) * (2 * o.window + 1));
    // Explained variance: the composite blurred to the right radius explains nearly all of the
    // frame's local variance where it is the same content. Where it is other content (a mask
    // holding wall texture, a bad registration) the cost only falls with r as blur flattens the
    // mismatch to its mean, and its minimum, at a large r, explains little.
    auto frame = d.input[t].unsqueeze(0);
    auto var = (box_filter(frame.pow(2), o.window) - box_filter(frame, o.window).pow(2))
                   .sum(1)[0]
                   .clamp_min(1e-8);
    auto explained = 1.0 - cmin / var;
    auto trust = ((explained - o.min_explained) / (1.0 - o.min_explained)).clamp(0, 1);
    auto wt = (conf > o.min_confidence).to(torch::kFloat32).mul(conf) * seen * trust;
    if (region.defined()) wt = wt * (region[t][0] > 0.5).to(torch::kFloat32);
    clock.next("radius: spread");
    Image guide = tensor_to_image(d.input[t].mean(0, true));
    Image src = tensor_to_image(r.unsqueeze(0));
    Image weight = tensor_to_image(wt.unsqueeze(0));
    // Near first: a window of `spread_px` keeps a flat subject (a face before a textured wall of
    // the same luma) from taking its neighbours' radius; what stays uncovered takes the wide pass.
    Image cover_near, cover_far;
    Image near = weighted_guided_filter(guide, src, weight, o.spread_px, 1e-3, &cover_near);
    const int far_px =
        o.spread_far_px > 0 ? o.spread_far_px : std::max<int>(o.spread_px, std::min(H, W) / 10);
    Image far = weighted_guided_filter(guide, src, weight, far_px, 1e-3, &cover_far);
    auto fn = image_to_tensor(near)[0], ff = image_to_tensor(far)[0];
    auto has_near = image_to_tensor(cover_near)[0] > 0, has_far = image_to_tensor(cover_far)[0] > 0;
    // Where nothing near was measured, no evidence of blur: radius 0 keeps the frame as it is
    // (the raw argmin there is whatever flattened a mismatch best, often the largest radius).
    return torch::where(has_near, fn, torch::where(has_far, ff, torch::zeros_like(ff)))
        .clamp(0.0, o.rmax);
}

// The largest relative radius any view reads at each canvas point [1,1,Hc,Wc]: where it is
// small, focus never changed there. Views near the other layer do not count where the point has
// views clear of it (the other layer's blurred rim passing over reads as a change of focus).
// Under a floor from tile spectra the views' quantile counts instead of their largest: there
// the largest is the stack's error, and a change of focus shows in many views.
torch::Tensor relative_max(const FitData& d, const LayerComposite& c, const torch::Tensor& region,
                           const std::vector<torch::Tensor>& out, bool spectral,
                           const StackCocOptions& o) {
    const int64_t T = d.frames, H = d.height, W = d.width, Hc = c.Hc, Wc = c.Wc;
    auto relmax = torch::zeros({1, 1, Hc, Wc});
    auto relmax_clear = torch::zeros({1, 1, Hc, Wc}), clear_seen = torch::zeros({1, 1, Hc, Wc});
    std::vector<torch::Tensor> rel_views, clear_views;
    for (int64_t t = 0; t < T; ++t) {
        auto inv = torch::inverse(c.to_canvas[t]);
        auto rel = warp_to_canvas(out[t].view({1, 1, H, W}), inv, Hc, Wc, true);
        relmax = torch::maximum(relmax, rel);
        if (region.defined()) {
            auto clear = warp_to_canvas(erode((region[t] > 0.5).to(torch::kFloat32).unsqueeze(0),
                                              o.floor_gate_clear_px),
                                        inv, Hc, Wc, true)
                             .gt(0.999)
                             .to(torch::kFloat32);
            relmax_clear = torch::maximum(relmax_clear, rel * clear);
            clear_seen = torch::maximum(clear_seen, clear);
            if (spectral) clear_views.push_back(clear * c.reg_valid[t]);
        }
        if (spectral)
            rel_views.push_back(
                torch::where(c.reg_valid[t] > 0.5, rel, torch::full_like(rel, NAN)));
    }
    if (region.defined()) relmax = torch::where(clear_seen > 0.5, relmax_clear, relmax);
    if (spectral) {
        auto R = torch::stack(rel_views);  // [T,1,1,Hc,Wc], NaN where the frame does not cover
        if (region.defined()) {
            auto C = torch::stack(clear_views) > 0.5;
            R = torch::where(C | (clear_seen < 0.5).unsqueeze(0), R, torch::full_like(R, NAN));
        }
        relmax = torch::nan_to_num(torch::nanquantile(R, o.floor_gate_quantile_spectral, 0), 0.0);
    }
    return relmax;
}

// The absolute floor added to the relative radii `out` (in place), only where focus never
// changed: a point some frame saw markedly blurrier than its sharpest view had a sharpest view
// the stack trusts, and a floor there only adds the readings' errors (docs/method.md, Radius
// estimation). The gate is 1 where the largest relative radius is under gate_lo, 0 over gate_hi.
void add_absolute_floor(const FitData& d, const LayerComposite& c, const torch::Tensor& region,
                        std::vector<torch::Tensor>& out, const StackCocOptions& o,
                        std::string* report, double* fixed_share) {
    const int64_t T = d.frames, H = d.height, W = d.width, Hc = c.Hc, Wc = c.Wc;
    std::string line;
    bool spectral = false;
    auto floor = absolute_floor(d, c.to_canvas, region, out, c.own_seen, o, line, &spectral)
                     .view({1, 1, Hc, Wc});
    auto relmax = relative_max(d, c, region, out, spectral, o);
    // Under a large floor the relative readings are noisy by more than gate_lo, and a change of
    // focus that matters there is a large one: the thresholds are at least these shares of it.
    auto glo =
        torch::maximum(torch::full_like(floor, o.floor_gate_lo), o.floor_gate_rel_lo * floor);
    auto ghi =
        torch::maximum(torch::full_like(floor, o.floor_gate_hi), o.floor_gate_rel_hi * floor);
    ghi = torch::maximum(ghi, glo + 1e-3);
    auto gate = ((ghi - relmax) / (ghi - glo)).clamp(0, 1);
    const auto ungated = floor;
    floor = floor * gate;
    const double share = floor.max().item<double>() > 0 ? gate.view({Hc, Wc})
                                                              .masked_select(c.own_seen > 0.5)
                                                              .gt(0.5)
                                                              .to(torch::kFloat32)
                                                              .mean()
                                                              .item<double>()
                                                        : 0.0;
    if (fixed_share) *fixed_share = share;
    if (report) {
        char buf[96];
        std::snprintf(buf, sizeof buf, ", applied where focus never changed (%.0f%% of the layer)",
                      100.0 * share);
        *report = line + (floor.max().item<double>() > 0 ? std::string(buf) : std::string());
    }
    at::parallel_for(0, T, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            auto f0 = warp_to_canvas(floor, c.to_canvas[t], H, W)[0][0].clamp_min(0);
            auto r = torch::sqrt(out[t] * out[t] + f0 * f0);  // second moments add
            if (spectral) {
                // Under a floor from tile spectra the layer is never sharper than the floor, so the
                // floor holds as a least radius where the gate closes; where it is open, the radius
                // is the floor itself (the relative readings there are the stack's error, and added
                // in quadrature they put frame-to-frame jitter on a static wall).
                auto u = warp_to_canvas(ungated, c.to_canvas[t], H, W)[0][0].clamp_min(0);
                r = torch::maximum(r, u);
                auto g = warp_to_canvas(gate, c.to_canvas[t], H, W)[0][0].clamp(0, 1);
                r = g * u + (1 - g) * r;
            }
            out[t] = r.clamp(0.0, o.rmax);
        }
    });
}

// One layer's pass. `to_ref` [T,3,3] float64 registers the layer (frame → reference);
// `region` [T,1,H,W] (frame coordinates) is where the layer is seen, or undefined for all of it.
// Only the layer's own pixels enter its all-in-focus composite and spread into flat areas, so a
// subject passing over a wall pixel does not become that pixel's "sharpest view", and the wall
// does not lend the subject its radius.
// `bank` holds the radius grid's kernels (both layers share it).
// Where a layer's pass reads crops of the frames (layer_radius_in_boxes): the whole frames, their
// registration and region build the composite over `canvas`, and crop t starts at `origin[t]`
// (y, x) of frame t.
struct CropSource {
    const FitData* whole = nullptr;
    torch::Tensor to_ref, region;
    AtlasBox canvas;
    std::vector<std::pair<int64_t, int64_t>> origin;
};

torch::Tensor layer_radius(const FitData& d, const torch::Tensor& to_ref_in,
                           const torch::Tensor& region, const UniformBlurBank& bank,
                           const StackCocOptions& o, std::string* report,
                           double* fixed_share = nullptr, const CropSource* crops = nullptr) {
    LayerComposite c =
        crops ? layer_composite(*crops->whole, crops->to_ref, crops->region, o, &crops->canvas)
              : layer_composite(d, to_ref_in, region, o, nullptr);
    if (crops) {
        // The composite of the whole frames, each crop mapped onto it.
        std::vector<torch::Tensor> shift;
        for (const auto& [y, x] : crops->origin) shift.push_back(translation(double(x), double(y)));
        c.to_canvas = torch::matmul(c.to_canvas, torch::stack(shift));
    }
    // Frames on the cores, each run of frames with its own blurs (a static camera's are made
    // once a run): a frame's radius is the same whichever run reads it.
    std::vector<torch::Tensor> out(d.frames);
    const bool grad = torch::GradMode::is_enabled();
    at::parallel_for(0, d.frames, 1, [&](int64_t t0, int64_t t1) {
        torch::AutoGradMode mode(grad);
        CompositeBlurs blurs;
        for (int64_t t = t0; t < t1; ++t) out[t] = relative_radius(d, c, region, t, bank, blurs, o);
    });
    ScopedTiming timing("radius: the floor");
    if (o.absolute) add_absolute_floor(d, c, region, out, o, report, fixed_share);
    return torch::stack(out).contiguous();
}

// The subject's pass over a box around it in each frame: its composite, blurs and costs over the
// subject's box instead of the whole frame (1080p×240, a subject on 2% of the frame: the pass ran
// on frames many times its size). The box reaches past the region by what any step reads around
// a region pixel: the blur's support and the cost window, and the wide spread's window (its
// first box pass then sees no weight the crop's border reflects, its second stays in the crop).
// So each region pixel's radius is the whole frame's, and only the region's is used (the visible
// surface takes the subject's radius inside its mask). Boxes of over half the frame take it whole.
torch::Tensor layer_radius_in_boxes(const FitData& d, const torch::Tensor& to_ref,
                                    const torch::Tensor& region, const UniformBlurBank& frame_bank,
                                    const StackCocOptions& o, std::string* report) {
    const int64_t T = d.frames, H = d.height, W = d.width;
    const int far = std::max<int>(o.spread_px, std::min(H, W) / 10);
    const int64_t margin =
        std::max<int64_t>(far, int64_t(std::ceil(o.rmax + 1)) + o.window + o.contrast_window) + 2;
    struct Box {
        int64_t y0 = 0, x0 = 0, y1 = 0, x1 = 0;  // region's bounds, end exclusive; empty: none
    };
    std::vector<Box> boxes(T);
    int64_t bh = 0, bw = 0;
    for (int64_t t = 0; t < T; ++t) {
        const auto m = region[t][0] > 0.5;
        const auto rows = m.any(1).nonzero(), cols = m.any(0).nonzero();
        if (rows.numel() == 0) continue;
        Box& b = boxes[t];
        b.y0 = rows.min().item<int64_t>(), b.y1 = rows.max().item<int64_t>() + 1;
        b.x0 = cols.min().item<int64_t>(), b.x1 = cols.max().item<int64_t>() + 1;
        bh = std::max(bh, b.y1 - b.y0), bw = std::max(bw, b.x1 - b.x0);
    }
    const int64_t ch = std::min(H, bh + 2 * margin), cw = std::min(W, bw + 2 * margin);
    if (!o.subject_boxes || bh == 0 || ch * cw > H * W / 2)
        return layer_radius(d, to_ref, region, frame_bank, o, report);
    FitData c;
    c.frames = int(T), c.height = int(ch), c.width = int(cw);
    c.blur = d.blur;
    c.static_camera = d.static_camera;
    c.input = torch::empty({T, 3, ch, cw});
    auto region_c = torch::empty({T, 1, ch, cw});
    std::vector<torch::Tensor> mats;
    std::vector<std::pair<int64_t, int64_t>> origin(T);
    int64_t oy = 0, ox = 0;  // a frame without the subject keeps the box before it
    for (int64_t t = 0; t < T; ++t) {
        const Box& b = boxes[t];
        if (b.y1 > b.y0) {
            oy = std::clamp((b.y0 + b.y1 - ch) / 2, int64_t(0), H - ch);
            ox = std::clamp((b.x0 + b.x1 - cw) / 2, int64_t(0), W - cw);
        }
        origin[t] = {oy, ox};
        c.input[t].copy_(d.input[t].narrow(1, oy, ch).narrow(2, ox, cw));
        region_c[t].copy_(region[t].narrow(1, oy, ch).narrow(2, ox, cw));
        mats.push_back(
            torch::matmul(to_ref[t].to(torch::kFloat64), translation(double(ox), double(oy))));
    }
    StackCocOptions oc = o;
    oc.spread_far_px = far;
    // The floor's cells as the whole frames' canvas lays them: their size from its side, and
    // the crops' canvas grown to start on its grid.
    const AtlasBox whole = mapped_frames_box(to_ref, H, W);
    oc.floor_cell_side = std::min(whole.height, whole.width);
    const int cell = std::max<int>(o.spread_px, int(oc.floor_cell_side / 15));
    const torch::Tensor to_ref_c = torch::stack(mats);
    const AtlasBox crops = mapped_frames_box(to_ref_c, ch, cw);
    AtlasBox canvas = crops;
    canvas.origin_x = whole.origin_x + std::floor((crops.origin_x - whole.origin_x) / cell) * cell;
    canvas.origin_y = whole.origin_y + std::floor((crops.origin_y - whole.origin_y) / cell) * cell;
    canvas.width = int64_t(std::ceil(crops.origin_x + crops.width - canvas.origin_x));
    canvas.height = int64_t(std::ceil(crops.origin_y + crops.height - canvas.origin_y));
    const UniformBlurBank bank(ch, cw, frame_bank.radii(), d.blur);
    CropSource src;
    src.whole = &d, src.to_ref = to_ref, src.region = region, src.canvas = canvas;
    src.origin = origin;
    const torch::Tensor rc = layer_radius(c, to_ref_c, region_c, bank, oc, report, nullptr, &src);
    auto out = torch::zeros({T, H, W});
    for (int64_t t = 0; t < T; ++t)
        out[t].narrow(0, origin[t].first, ch).narrow(1, origin[t].second, cw).copy_(rc[t]);
    return out;
}

}  // namespace

torch::Tensor warp_to_canvas(const torch::Tensor& src, const torch::Tensor& m, int64_t H, int64_t W,
                             bool zeros, bool shifts_as_copies) {
    // A whole-pixel translation (a static camera's frames on their canvas) reads each source
    // pixel itself: a shifted copy, padded as the sampler pads (the sampler's sum of taps at
    // whole pixels equals it to float rounding).
    const auto a = m.to(torch::kFloat64).contiguous();
    const double* e = a.data_ptr<double>();
    if (shifts_as_copies && e[0] == 1 && e[1] == 0 && e[3] == 0 && e[4] == 1 && e[6] == 0 &&
        e[7] == 0 && e[8] == 1 && e[2] == std::round(e[2]) && e[5] == std::round(e[5])) {
        const int64_t dx = int64_t(e[2]), dy = int64_t(e[5]), h = src.size(2), w = src.size(3);
        const int64_t top = std::max<int64_t>(0, -dy), left = std::max<int64_t>(0, -dx);
        const int64_t bottom = std::max<int64_t>(0, dy + H - h),
                      right = std::max<int64_t>(0, dx + W - w);
        auto opts = F::PadFuncOptions({left, right, top, bottom});
        auto padded = F::pad(
            src, zeros ? opts.mode(torch::kConstant).value(0) : opts.mode(torch::kReplicate));
        return padded.narrow(2, dy + top, H).narrow(3, dx + left, W).contiguous();
    }
    auto ys = torch::arange(H, torch::kFloat64), xs = torch::arange(W, torch::kFloat64);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto pts =
        torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({H * W}, torch::kFloat64)}, 0);
    auto p = torch::matmul(m, pts);
    auto xy = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1)).t().view({1, H, W, 2});
    // Normalised by the source's size (align_corners = false).
    auto scale = torch::tensor({2.0 / src.size(3), 2.0 / src.size(2)}, torch::kFloat64);
    auto grid = ((xy + 0.5) * scale - 1.0).to(torch::kFloat32).expand({src.size(0), H, W, 2});
    return torch::grid_sampler(src, grid, zeros ? 0 : 2, zeros ? 0 : 1,
                               false);  // bilinear/zeros or bicubic/border
}

void split_radius_by_layer(FitData& d, int margin) {
    d.radius_fg = d.radius_bg = torch::Tensor();
    if (!d.has_subject || !d.mask.defined()) return;
    torch::NoGradGuard no_grad;
    const int64_t H = d.height, W = d.width;
    // Frame by frame, into clip arrays: a long clip's maps need not fit in memory.
    // A frame a core: each frame's maps read that frame's radius and mask only.
    auto out_fg = d.clip_array(d.radius.sizes(), "radius_fg"),
         out_bg = d.clip_array(d.radius.sizes(), "radius_bg");
    at::parallel_for(0, d.frames, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            out_fg[t].copy_(d.radius[t]);
            out_bg[t].copy_(d.radius[t]);
            // Without a pixel of the subject both layers keep the visible surface's map. With one,
            // only a box around it changes: every filter below reads at most `far` around the
            // subject's pixels, so the box is read instead of the frame (the same values but for
            // the fills, which a box's pyramid makes from the same neighbours).
            const auto fg_frame = d.mask[t][0] > 0.5;  // [H,W]
            const auto rows = fg_frame.any(1).nonzero(), cols = fg_frame.any(0).nonzero();
            if (rows.numel() == 0) continue;
            const int64_t y0 = rows.min().item<int64_t>(), y1 = rows.max().item<int64_t>() + 1,
                          x0 = cols.min().item<int64_t>(), x1 = cols.max().item<int64_t>() + 1;
            const double area = fg_frame.sum().item<double>();
            const int k = std::max(margin, int(0.3 * std::sqrt(area / M_PI)));
            const int reach = std::max(margin, int(std::sqrt(area / M_PI)));
            auto box = [&](const torch::Tensor& x, int64_t g) {  // [.., H, W] → its box grown by g
                const int64_t by0 = std::max<int64_t>(0, y0 - g),
                              bx0 = std::max<int64_t>(0, x0 - g);
                return x.narrow(-2, by0, std::min(H, y1 + g) - by0)
                    .narrow(-1, bx0, std::min(W, x1 + g) - bx0);
            };
            // The subject's radius is read where its mask is surest (its core); far from the mask
            // its layer takes the visible surface's, so the box reaches as far as the subject's
            // radius does.
            const double rmax_near = box(d.radius[t], k + margin + 2).max().item<double>();
            const int64_t g = std::max<int64_t>(reach + int64_t(std::ceil(rmax_near)) + 2, k) + 2;
            const auto r = box(d.radius[t], g).unsqueeze(0).unsqueeze(0);  // [1,1,h,w]
            const auto fg = box(fg_frame, g).to(torch::kFloat32).unsqueeze(0).unsqueeze(0);
            const bool whole = r.size(2) == H && r.size(3) == W;
            auto keep_fg = erode(fg, margin), keep_bg = erode(1.0 - fg, margin);
            torch::Tensor fg_region;  // where the subject's radius applies (undefined: everywhere)
            // An automatic mask is a blob around a blurred subject (wider than the silhouette by
            // about the blur, and missing a part here and there): the map inside it holds the
            // wall's radius at its rim, and the wall's side of it the subject's radius where it
            // missed a part. The subject's radius is read where the mask is surest (its core) and
            // only values near it stay the subject's; the same values next to the mask leave the
            // wall's (docs/method.md, Layered reblur).
            auto core = erode(fg, k);
            if (core.sum().item<double>() < 1) core = keep_fg;
            if (core.sum().item<double>() >= 1) {
                const double r_core = r.masked_select(core > 0.5).median().item<double>();
                const double tol = std::max(1.0, 0.25 * r_core);
                auto like_subject = ((r - r_core).abs() <= tol).to(torch::kFloat32);
                auto fg_kept = keep_fg * like_subject;
                keep_fg = fg_kept.sum().item<double>() >= 1 ? fg_kept : core;
                auto near = max_filter(fg, reach);
                auto bg_kept = keep_bg * (1.0 - near * like_subject);
                if (!whole || bg_kept.sum().item<double>() >= 1) keep_bg = bg_kept;
                // Far from the mask the subject's layer is transparent and its radius only costs
                // time (the lens blur scatters every source pixel over its radius): there it takes
                // the visible surface's (docs/method.md, Layered reblur).
                const int far = reach + int(std::ceil(r_core)) + 2;
                fg_region = max_filter(fg, far);
            }
            // A layer without a sure pixel keeps the visible surface's map.
            auto one = [&](const torch::Tensor& sure) {
                return sure.sum().item<double>() > 0 ? fill_from(r, sure)[0][0] : r[0][0];
            };
            box(out_fg[t], g)
                .copy_(fg_region.defined()
                           ? torch::where(fg_region[0][0] > 0.5, one(keep_fg), r[0][0])
                           : one(keep_fg));
            // Outside the box the wall's layer is sure everywhere (a fill keeps what it is given).
            box(out_bg[t], g).copy_(one(keep_bg));
        }
    });
    d.radius_fg = out_fg;
    d.radius_bg = out_bg;
}

torch::Tensor estimate_radius_from_stack(const FitData& d, const StackCocOptions& o,
                                         StackCocReport* report) {
    std::string line_bg, line_fg;
    torch::NoGradGuard no_grad;
    std::vector<double> radii;
    for (double r = 0; r <= o.rmax + 1e-9; r += o.rstep) radii.push_back(r);
    const UniformBlurBank bank(d.height, d.width, radii, d.blur);
    const bool layered = d.has_subject && d.mask.defined();
    if (!layered) {
        auto r = layer_radius(d, d.to_ref, {}, bank, o, &line_bg,
                              report ? &report->fixed_focus_share : nullptr);
        if (report) report->summary = o.absolute ? "absolute floor: " + line_bg : "relative only";
        return r;
    }
    // Two layers: the background registered by the camera homographies, the subject by its own
    // track (a moving subject is not where the wall was: compared pixel by pixel across frames it
    // reads as blur, even in focus).
    auto mask = (d.mask > 0.5).to(torch::kFloat32);
    auto bg = layer_radius(d, d.to_ref, 1.0 - mask, bank, o, &line_bg,
                           report ? &report->fixed_focus_share : nullptr);
    std::vector<double> vx, vy, sc;
    subject_track(d, vx, vy, &sc);
    std::vector<torch::Tensor> mats;
    const auto from_track0 = torch::inverse(subject_to_track(vx[0], vy[0], sc[0]));
    for (int64_t t = 0; t < d.frames; ++t)
        mats.push_back(sc[t] == 1.0 && sc[0] == 1.0
                           ? translation(vx[0] - vx[t], vy[0] - vy[t])
                           : torch::matmul(from_track0, subject_to_track(vx[t], vy[t], sc[t])));
    auto fg = layer_radius_in_boxes(d, torch::stack(mats), mask, bank, o, &line_fg);
    if (report)
        report->summary = o.absolute ? "absolute floor: wall " + line_bg + "; subject " + line_fg
                                     : "relative only";
    return torch::where(mask.squeeze(1) > 0.5, fg, bg).contiguous();
}

}  // namespace refocus
