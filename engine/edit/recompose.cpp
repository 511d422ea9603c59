// The refocused frame; see recompose.h.
#include "edit/recompose.h"

#include "edit/atlas_edit.h"

#include <torch/torch.h>

#include <mutex>

#include "fit/fit_engine.h"
#include "io/tensor_image.h"
#include "util/error.h"

namespace refocus {

FrameMaps frame_maps(FitEngine& engine, int t) {
    return frame_maps(engine, t, {}, {});
}

FrameMaps frame_maps(FitEngine& engine, int t, const torch::Tensor& bg_delta,
                     const torch::Tensor& fg_delta) {
    torch::NoGradGuard no_grad;
    Layers L = engine.render_frame(t);  // holds model_mutex() while it renders
    const Layers model = L;
    apply_edits(L, bg_delta, fg_delta);
    const Layers edited = L;
    engine.apply_fallback(L, t, &model);
    FrameMaps m = frame_maps(L);
    if (!engine.has_atlas() || m.uv_bg.empty() || !L.bg.defined()) return m;
    // A preview samples the (edited) atlases itself: the fix is what export's plate adds over
    // that, the output rules' change plus the engine's own sampling (prefilter, warps) over a
    // bilinear tap of the model's atlases. The preview then draws the exported plate, and paint
    // on the atlas shows on top as it does in the export.
    Image bg_atlas, fg_atlas;
    {
        std::lock_guard<std::mutex> lock(engine.model_mutex());
        bg_atlas = tensor_to_image(engine.model().atlas_bg().contiguous());
        const torch::Tensor fg = engine.model().atlas_fg();
        if (fg.defined() && !m.fg.empty()) fg_atlas = tensor_to_image(fg.contiguous());
    }
    const bool two = !fg_atlas.empty();
    const PreviewLayers sampled = composite_layers(
        bg_atlas, m.uv_bg, fg_atlas, two ? m.uv_fg : Image(), two ? m.alpha : Image());
    auto fix = [](const torch::Tensor& out, const torch::Tensor& edit, const torch::Tensor& base,
                  const Image& tap) {
        return tensor_to_image(((out - edit)[0] + (base[0] - image_to_tensor(tap))).contiguous());
    };
    m.bg_fix = fix(L.bg, edited.bg, model.bg, sampled.background);
    if (two) m.fg_fix = fix(L.fg, edited.fg, model.fg, sampled.foreground);
    return m;
}

Image confidence_image(const FitEngine& engine, int t) {
    torch::NoGradGuard no_grad;
    auto k = engine.confidence(t);
    auto w = engine.model_weight(t);
    if (!w.defined()) w = torch::ones_like(k);
    return tensor_to_image(torch::cat({k[0], w[0]}, 0).contiguous());
}

FrameMaps frame_maps(const Layers& L) {
    auto img = [](const torch::Tensor& x) {
        return x.defined() ? tensor_to_image(x[0].contiguous()) : Image();
    };
    auto uv = [](const torch::Tensor& x) {  // [1,H,W,2] → 2-channel image
        return x.defined() ? tensor_to_image(x[0].permute({2, 0, 1}).contiguous()) : Image();
    };
    FrameMaps m;
    m.sharp = img(L.sharp);
    m.bg = img(L.bg);
    m.uv_bg = uv(L.uv_bg);
    if (L.fg.defined() && L.alpha.defined() && L.uv_fg.defined()) {
        m.fg = img(L.fg);
        m.alpha = img(L.alpha);
        m.uv_fg = uv(L.uv_fg);
    }
    return m;
}

Image render_refocused(const FrameMaps& m, const DepthModel& depth, int t, const PreviewLens& lens,
                       int threads) {
    if (m.uv_bg.empty())
        throw Error("refocus: frame " + std::to_string(t) +
                    " has no UV map (the perframe preset has no atlas)");
    const bool two = !m.fg.empty();
    return render_dof(preview_layers(m), depth.frame_depth(t, m.uv_bg, two ? m.uv_fg : Image()),
                      lens, threads);
}

PreviewLayers preview_layers(const FrameMaps& m) {
    PreviewLayers layers;
    layers.composite = m.sharp;
    layers.background = m.bg.empty() ? m.sharp : m.bg;
    const bool two = !m.fg.empty();
    const int w = layers.background.width, h = layers.background.height;
    layers.foreground = two ? m.fg : Image(w, h, 3);
    layers.alpha = two ? m.alpha : Image(w, h, 1);
    return layers;
}

}  // namespace refocus
