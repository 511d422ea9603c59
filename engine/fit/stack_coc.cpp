#include "fit/stack_coc.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include "fit/atlas_geometry.h"
#include "fit/tensor_image.h"
#include "ops/lens_blur.h"
#include "prepare/coc.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

torch::Tensor box(const torch::Tensor& x, int r) {  // [N,C,H,W] box mean, same size
    const int k = 2 * r + 1;
    return F::avg_pool2d(F::pad(x, F::PadFuncOptions({r, r, r, r}).mode(torch::kReplicate)),
                         F::AvgPool2dFuncOptions(k).stride(1));
}

// Warp [N,C,h,w] images onto an H x W grid: output pixel p reads the source at m·p (bicubic).
// `zeros` pads outside the source with 0 (for validity maps), otherwise with the border value.
torch::Tensor warp(const torch::Tensor& src, const torch::Tensor& m, int64_t H, int64_t W, bool zeros = false) {
    auto ys = torch::arange(H, torch::kFloat64), xs = torch::arange(W, torch::kFloat64);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto pts = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({H * W}, torch::kFloat64)}, 0);
    auto p = torch::matmul(m, pts);
    auto xy = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1)).t().view({1, H, W, 2});
    // Normalised by the source's size (align_corners = false).
    auto scale = torch::tensor({2.0 / src.size(3), 2.0 / src.size(2)}, torch::kFloat64);
    auto grid = ((xy + 0.5) * scale - 1.0).to(torch::kFloat32).expand({src.size(0), H, W, 2});
    return torch::grid_sampler(src, grid, zeros ? 0 : 2, zeros ? 0 : 1, false);  // bilinear/zeros or bicubic/border
}

// Where a [N,1,H,W] 0/1 map is 1 over the whole (2r+1)² window around a pixel.
torch::Tensor erode(const torch::Tensor& valid, int r) {
    return -F::max_pool2d(-valid, F::MaxPool2dFuncOptions(2 * r + 1).stride(1).padding(r));
}

// One layer's pass. `to_ref` [T,3,3] float64 registers the layer (frame → reference);
// `region` [T,1,H,W] (frame coordinates) is where the layer is seen, or undefined for all of it.
// Only the layer's own pixels enter its all-in-focus composite and spread into flat areas, so a
// subject passing over a wall pixel does not become that pixel's "sharpest view", and the wall
// does not lend the subject its radius.
torch::Tensor layer_radius(const FitData& d, const torch::Tensor& to_ref_in, const torch::Tensor& region,
                           const StackCocOptions& o) {
    const int64_t T = d.frames, H = d.height, W = d.width;
    // 1. Every frame on a canvas in reference coordinates that covers all of them (canvas pixel
    //    p reads frame t at to_canvas_t⁻¹ p). A canvas of the reference frame's own size, read
    //    with border padding, gave content that enters a pan later smeared border pixels as its
    //    "sharpest view": the synth pan clip's left strip read 4-8 px of blur on a wall in focus.
    const AtlasBox box_ref = mapped_frames_box(to_ref_in, H, W);
    const int64_t Hc = box_ref.height, Wc = box_ref.width;
    auto to_canvas = torch::matmul(translation(-box_ref.origin_x, -box_ref.origin_y).unsqueeze(0),
                                   to_ref_in.to(torch::kFloat64));
    auto ones = torch::ones({1, 1, H, W});
    std::vector<torch::Tensor> reg, reg_valid, reg_region;
    for (int64_t t = 0; t < T; ++t) {
        auto inv = torch::inverse(to_canvas[t]);
        reg.push_back(warp(d.input[t].unsqueeze(0), inv, Hc, Wc)[0]);
        reg_valid.push_back((warp(ones, inv, Hc, Wc, true)[0] > 0.999).to(torch::kFloat32));
        if (region.defined()) reg_region.push_back(warp(region[t].unsqueeze(0), inv, Hc, Wc, true)[0].clamp(0, 1));
    }
    auto stack = torch::stack(reg);  // [T,3,Hc,Wc]
    // 2. All-in-focus: local contrast (box-filtered squared Laplacian of luma) picks, softly,
    //    the sharpest frame at each pixel, among the views whose contrast window lies inside
    //    their frame.
    auto luma = (0.299 * stack.select(1, 0) + 0.587 * stack.select(1, 1) + 0.114 * stack.select(1, 2)).unsqueeze(1);
    auto lap = F::conv2d(F::pad(luma, F::PadFuncOptions({1, 1, 1, 1}).mode(torch::kReplicate)),
                         torch::tensor({0.f, 1.f, 0.f, 1.f, -4.f, 1.f, 0.f, 1.f, 0.f}).view({1, 1, 3, 3}));
    auto valid = erode(torch::stack(reg_valid), o.contrast_window + 1);  // [T,1,Hc,Wc]
    auto contrast = box(lap.pow(2), o.contrast_window) * valid;
    auto w = (contrast / contrast.amax({0}, true).clamp_min(1e-12)).pow(8) * valid;
    if (region.defined()) {
        // The layer's own views first; where it is never seen, every view (a fallback that the
        // final selection by region does not use anyway).
        auto own = torch::stack(reg_region);                 // [T,1,Hc,Wc]
        auto wo = w * (own > 0.5).to(torch::kFloat32);
        w = torch::where(wo.sum(0, true) > 1e-6, wo, w);
    }
    auto wsum = w.sum(0);                                         // [1,Hc,Wc]
    auto aif = (stack * w).sum(0) / wsum.clamp_min(1e-12);      // [3,Hc,Wc]
    auto covered = (wsum > 1e-12).to(torch::kFloat32).unsqueeze(0);  // [1,1,Hc,Wc]

    // 3. Per frame: the radius whose blur of the AIF matches the frame best, locally.
    std::vector<double> radii;
    for (double r = 0; r <= o.rmax + 1e-9; r += o.rstep) radii.push_back(r);
    const int64_t K = radii.size();
    std::vector<torch::Tensor> out;
    const LensBlurParams& bp = d.blur;
    for (int64_t t = 0; t < T; ++t) {
        auto aif_t = warp(aif.unsqueeze(0), to_canvas[t], H, W)[0].contiguous();
        // Pixels whose matching window reads canvas the composite does not cover are not measured.
        auto seen = erode(warp(covered, to_canvas[t], H, W, true).gt(0.999).to(torch::kFloat32),
                          o.window)[0][0];
        std::vector<torch::Tensor> costs;
        for (double r : radii) {
            auto b = r < bp.min_radius ? aif_t : lens_blur(aif_t, torch::full({H, W}, float(r)), bp);
            costs.push_back((b - d.input[t]).pow(2).sum(0, true));
        }
        auto c = box(torch::stack(costs), o.window).squeeze(1);  // [K,H,W]
        auto best = c.argmin(0);                                  // [H,W]
        // Sub-step refinement: parabola through the neighbours of the minimum.
        auto bi = best.clamp(1, K - 2);
        auto c0 = c.gather(0, (bi - 1).unsqueeze(0))[0], c1 = c.gather(0, bi.unsqueeze(0))[0],
             c2 = c.gather(0, (bi + 1).unsqueeze(0))[0];
        auto denom = (c0 - 2 * c1 + c2);
        auto off = torch::where(denom > 1e-12, 0.5 * (c0 - c2) / denom.clamp_min(1e-12),
                                torch::zeros_like(denom)).clamp(-0.5, 0.5);
        auto interior = (best >= 1) & (best <= K - 2);
        auto r = best.to(torch::kFloat32) * o.rstep + torch::where(interior, off, torch::zeros_like(off)) * o.rstep;
        auto cmin = std::get<0>(c.min(0));
        auto conf = (std::get<0>(c.max(0)) - cmin) / (float(2 * o.window + 1) * (2 * o.window + 1));
        // Explained variance: a blurred composite that is the same content as the frame explains
        // nearly all of the frame's local variance at the right radius. Where the composite is
        // other content (a mask that holds wall texture moving against the subject, a bad
        // registration) the cost only falls with r as blur flattens the mismatch to its mean, and
        // its minimum, at a large r, explains little. Measured on the synth pan clip: a subject
        // never in focus read 10.5-12.8 px (truth 7.15; relative to its sharpest view, 0).
        auto frame = d.input[t].unsqueeze(0);
        auto var = (box(frame.pow(2), o.window) - box(frame, o.window).pow(2)).sum(1)[0].clamp_min(1e-8);
        auto explained = 1.0 - cmin / var;
        auto trust = ((explained - o.min_explained) / (1.0 - o.min_explained)).clamp(0, 1);
        // 4. Spread from where the match is measured (texture, on this layer) into flat regions.
        auto wt = (conf > o.min_confidence).to(torch::kFloat32).mul(conf) * seen * trust;
        if (region.defined()) wt = wt * (region[t][0] > 0.5).to(torch::kFloat32);
        Image guide = tensor_to_image(d.input[t].mean(0, true));
        Image src = tensor_to_image(r.unsqueeze(0));
        Image weight = tensor_to_image(wt.unsqueeze(0));
        // Near first: a window of `spread_px` keeps a flat subject (a face in front of a textured
        // wall of the same luma) from taking its neighbours' radius; what stays uncovered takes
        // the wide pass. Synth tripod clip (320x180), radius MAE on the subject over frames
        // 0,3,..,27: one spread of H/10 = 18 px 1.65 px, the head read as wall in every frame
        // (and the fit painted wall texture over it); 6 px, then 18: 1.04 px. 1-min fast: 27.16 ->
        // 29.06 dB.
        Image cover_near, cover_far;
        Image near = weighted_guided_filter(guide, src, weight, o.spread_px, 1e-3, &cover_near);
        Image far = weighted_guided_filter(guide, src, weight, std::max<int>(o.spread_px, std::min(H, W) / 10),
                                           1e-3, &cover_far);
        auto fn = image_to_tensor(near)[0], ff = image_to_tensor(far)[0];
        auto has_near = image_to_tensor(cover_near)[0] > 0, has_far = image_to_tensor(cover_far)[0] > 0;
        // Where nothing near was measured, no evidence of blur: radius 0 keeps the frame as it is
        // (the raw argmin there is whatever flattened a mismatch best, often the largest radius).
        auto ft = torch::where(has_near, fn, torch::where(has_far, ff, torch::zeros_like(ff)));
        out.push_back(ft.clamp(0.0, o.rmax));
    }
    return torch::stack(out).contiguous();
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

}  // namespace

void split_radius_by_layer(FitData& d, int margin) {
    d.radius_fg = d.radius_bg = torch::Tensor();
    if (!d.has_subject || !d.mask.defined()) return;
    torch::NoGradGuard no_grad;
    auto r = d.radius.unsqueeze(1);                                 // [T,1,H,W]
    auto fg = (d.mask > 0.5).to(torch::kFloat32);
    auto sure_fg = erode(fg, margin), sure_bg = erode(1.0 - fg, margin);
    std::vector<torch::Tensor> rf, rb;
    for (int64_t t = 0; t < d.frames; ++t) {
        auto keep_fg = sure_fg[t].unsqueeze(0), keep_bg = sure_bg[t].unsqueeze(0);
        torch::Tensor fg_region;  // where the subject's radius applies (undefined: everywhere)
        // An automatic mask is a blob around a blurred subject (wider than the silhouette by
        // about the blur, and missing a part here and there): the map inside it holds the wall's
        // radius at its rim, and the wall's side of it the subject's radius where it missed a
        // part. The subject's radius is read where the mask is surest (its core) and only
        // values near it stay the subject's; the same values next to the mask leave the wall's.
        // Synth clips, 600 steps, the masks as they are -> this: pan (true radius) 24.36 ->
        // 24.92 dB (split by the true alpha: 24.89), rack 27.84 -> 28.74, hunt 25.05 -> 25.04;
        // walkout 20.13 -> 20.15; estimated radius: rack 25.76 -> 25.96, hunt 22.39 -> 22.37.
        const double area = fg[t].sum().item<double>();
        const int k = std::max(margin, int(0.3 * std::sqrt(area / M_PI)));
        auto core = erode(fg[t].unsqueeze(0), k);
        if (core.sum().item<double>() < 1) core = keep_fg;
        if (core.sum().item<double>() >= 1) {
            const auto rt = r[t].unsqueeze(0);
            const double r_core = rt.masked_select(core > 0.5).median().item<double>();
            const double tol = std::max(1.0, 0.25 * r_core);
            auto like_subject = ((rt - r_core).abs() <= tol).to(torch::kFloat32);
            auto fg_kept = keep_fg * like_subject;
            keep_fg = fg_kept.sum().item<double>() >= 1 ? fg_kept : core;
            const int reach = std::max(margin, int(std::sqrt(area / M_PI)));
            auto near = F::max_pool2d(fg[t].unsqueeze(0), F::MaxPool2dFuncOptions(2 * reach + 1).stride(1).padding(reach));
            auto bg_kept = keep_bg * (1.0 - near * like_subject);
            if (bg_kept.sum().item<double>() >= 1) keep_bg = bg_kept;
            // Far from the mask the subject's layer is transparent and its radius only costs
            // time (the lens blur scatters every source pixel over its radius): there it takes
            // the visible surface's. Synth pan, true radius, 10 min: 2771 steps (25.92 dB) with
            // the subject's everywhere, 3209 (25.99) with this.
            const int far = reach + int(std::ceil(r_core)) + 2;
            fg_region = F::max_pool2d(fg[t].unsqueeze(0), F::MaxPool2dFuncOptions(2 * far + 1).stride(1).padding(far));
        }
        // A frame without a sure pixel of a layer keeps the visible surface's map for it.
        auto one = [&](const torch::Tensor& sure) {
            return sure.sum().item<double>() > 0 ? fill_from(r[t].unsqueeze(0), sure)[0][0] : d.radius[t];
        };
        rf.push_back(fg_region.defined() ? torch::where(fg_region[0][0] > 0.5, one(keep_fg), d.radius[t])
                                         : one(keep_fg));
        rb.push_back(one(keep_bg));
    }
    d.radius_fg = torch::stack(rf).contiguous();
    d.radius_bg = torch::stack(rb).contiguous();
}

torch::Tensor estimate_radius_from_stack(const FitData& d, const StackCocOptions& o) {
    torch::NoGradGuard no_grad;
    const bool layered = d.has_subject && d.mask.defined();
    if (!layered) return layer_radius(d, d.to_ref, {}, o);
    // Two layers: the background registered by the camera homographies, the subject by its own
    // track (a moving subject is not where the wall was: compared pixel by pixel across frames it
    // reads as blur; measured on the synth rack clip: 3-3.7 px on a subject in focus).
    auto mask = (d.mask > 0.5).to(torch::kFloat32);
    auto bg = layer_radius(d, d.to_ref, 1.0 - mask, o);
    std::vector<double> vx, vy, sc;
    subject_track(d, vx, vy, &sc);
    std::vector<torch::Tensor> mats;
    const auto from_track0 = torch::inverse(subject_to_track(vx[0], vy[0], sc[0]));
    for (int64_t t = 0; t < d.frames; ++t)
        mats.push_back(sc[t] == 1.0 && sc[0] == 1.0
                           ? translation(vx[0] - vx[t], vy[0] - vy[t])
                           : torch::matmul(from_track0, subject_to_track(vx[t], vy[t], sc[t])));
    auto fg = layer_radius(d, torch::stack(mats), mask, o);
    return torch::where(mask.squeeze(1) > 0.5, fg, bg).contiguous();
}

}  // namespace refocus
