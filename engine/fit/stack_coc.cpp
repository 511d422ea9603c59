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

// Warp [N,C,H,W] images sampled at the pixel positions given by homography `m` applied to the
// output pixel grid (output pixel p reads source at m·p).
torch::Tensor warp(const torch::Tensor& src, const torch::Tensor& m, int64_t H, int64_t W) {
    auto ys = torch::arange(H, torch::kFloat64), xs = torch::arange(W, torch::kFloat64);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto pts = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({H * W}, torch::kFloat64)}, 0);
    auto p = torch::matmul(m, pts);
    auto xy = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1)).t().view({1, H, W, 2});
    auto scale = torch::tensor({2.0 / W, 2.0 / H}, torch::kFloat64);
    auto grid = ((xy + 0.5) * scale - 1.0).to(torch::kFloat32).expand({src.size(0), H, W, 2});
    return torch::grid_sampler(src, grid, 2, 1, false);  // bicubic, border
}

// One layer's pass. `to_ref` [T,3,3] float64 registers the layer (frame → reference);
// `region` [T,1,H,W] (frame coordinates) is where the layer is seen, or undefined for all of it.
// Only the layer's own pixels enter its all-in-focus composite and spread into flat areas, so a
// subject passing over a wall pixel does not become that pixel's "sharpest view", and the wall
// does not lend the subject its radius.
torch::Tensor layer_radius(const FitData& d, const torch::Tensor& to_ref_in, const torch::Tensor& region,
                           const StackCocOptions& o) {
    const int64_t T = d.frames, H = d.height, W = d.width;
    auto to_ref = to_ref_in.to(torch::kFloat64);
    // 1. Every frame in reference coordinates (reference pixel p reads frame t at H_t⁻¹ p).
    std::vector<torch::Tensor> reg, reg_region;
    for (int64_t t = 0; t < T; ++t) {
        auto inv = torch::inverse(to_ref[t]);
        reg.push_back(warp(d.input[t].unsqueeze(0), inv, H, W)[0]);
        if (region.defined()) reg_region.push_back(warp(region[t].unsqueeze(0), inv, H, W)[0].clamp(0, 1));
    }
    auto stack = torch::stack(reg);  // [T,3,H,W]
    // 2. All-in-focus: local contrast (box-filtered squared Laplacian of luma) picks, softly,
    //    the sharpest frame at each pixel.
    auto luma = (0.299 * stack.select(1, 0) + 0.587 * stack.select(1, 1) + 0.114 * stack.select(1, 2)).unsqueeze(1);
    auto lap = F::conv2d(F::pad(luma, F::PadFuncOptions({1, 1, 1, 1}).mode(torch::kReplicate)),
                         torch::tensor({0.f, 1.f, 0.f, 1.f, -4.f, 1.f, 0.f, 1.f, 0.f}).view({1, 1, 3, 3}));
    auto contrast = box(lap.pow(2), o.contrast_window);  // [T,1,H,W]
    auto w = (contrast / contrast.amax({0}, true).clamp_min(1e-12)).pow(8);
    if (region.defined()) {
        // The layer's own views first; where it is never seen, every view (a fallback that the
        // final selection by region does not use anyway).
        auto own = torch::stack(reg_region);                 // [T,1,H,W]
        auto wo = w * (own > 0.5).to(torch::kFloat32);
        w = torch::where(wo.sum(0, true) > 1e-6, wo, w);
    }
    auto aif = (stack * w).sum(0) / w.sum(0).clamp_min(1e-12);  // [3,H,W]

    // 3. Per frame: the radius whose blur of the AIF matches the frame best, locally.
    std::vector<double> radii;
    for (double r = 0; r <= o.rmax + 1e-9; r += o.rstep) radii.push_back(r);
    const int64_t K = radii.size();
    std::vector<torch::Tensor> out;
    LensBlurParams bp;
    for (int64_t t = 0; t < T; ++t) {
        auto aif_t = warp(aif.unsqueeze(0), to_ref[t], H, W)[0].contiguous();
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
        auto conf = (std::get<0>(c.max(0)) - std::get<0>(c.min(0))) / (float(2 * o.window + 1) * (2 * o.window + 1));
        // 4. Spread from where the match is measured (texture, on this layer) into flat regions.
        auto wt = (conf > o.min_confidence).to(torch::kFloat32).mul(conf);
        if (region.defined()) wt = wt * (region[t][0] > 0.5).to(torch::kFloat32);
        Image guide = tensor_to_image(d.input[t].mean(0, true));
        Image src = tensor_to_image(r.unsqueeze(0));
        Image weight = tensor_to_image(wt.unsqueeze(0));
        Image cover;
        Image filled = weighted_guided_filter(guide, src, weight, std::max<int>(4, std::min(H, W) / 10), 1e-3, &cover);
        auto ft = image_to_tensor(filled)[0];
        auto has = image_to_tensor(cover)[0] > 0;
        out.push_back(torch::where(has, ft, r).clamp(0.0, o.rmax));
    }
    return torch::stack(out).contiguous();
}

}  // namespace

torch::Tensor estimate_radius_from_stack(const FitData& d, const StackCocOptions& o) {
    torch::NoGradGuard no_grad;
    const bool layered = d.has_subject && d.mask.defined();
    if (!layered) return layer_radius(d, d.to_ref, {}, o);
    // Two layers: the background registered by the camera homographies, the subject by its own
    // track (a moving subject is not where the wall was: compared pixel by pixel across frames it
    // reads as blur; measured on the synth rack clip: 3-3.7 px on a subject in focus).
    auto mask = (d.mask > 0.5).to(torch::kFloat32);
    auto bg = layer_radius(d, d.to_ref, 1.0 - mask, o);
    std::vector<double> vx, vy;
    subject_track(d.mask, vx, vy);
    std::vector<torch::Tensor> mats;
    for (int64_t t = 0; t < d.frames; ++t) mats.push_back(translation(vx[0] - vx[t], vy[0] - vy[t]));
    auto fg = layer_radius(d, torch::stack(mats), mask, o);
    return torch::where(mask.squeeze(1) > 0.5, fg, bg).contiguous();
}

}  // namespace refocus
