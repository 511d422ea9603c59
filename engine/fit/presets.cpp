#include "fit/presets.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>

#include "fit/fast_model.h"
#include "fit/paper_model.h"
#include "fit/perframe_model.h"
#include "fit/settings.h"
#include "util/error.h"

namespace refocus {

namespace {

std::unique_ptr<FitModel> make_fast(const FitData& data, const Settings& s, uint64_t) {
    FastModelOptions o;
    apply_settings(s, o);
    // An estimated radius's errors want the full TV on a deblurring path's atlas; a given
    // radius takes less (docs/method.md, Deblurring path).
    o.deblur_tv = data.radius_given ? o.deblur_tv_given : o.deblur_tv;
    // The atlases reach past the frame by the widest blur support, so that edge pixels are
    // explained by the scene beyond the edge (FitModel::render_padded).
    if (!s.has("fast.pad"))
        o.pad = int(std::clamp(
            std::ceil(lens_blur_support(data.radius.max().item<double>(), data.blur)), 0.0, 48.0));
    o.atlas_scale = data.atlas_scale;
    return std::make_unique<FastModel>(data, o);
}

std::unique_ptr<FitModel> make_paper(const FitData& data, const Settings& s, uint64_t seed) {
    PaperModelOptions o;
    apply_settings(s, o);
    return std::make_unique<PaperModel>(data, o, seed);
}

std::unique_ptr<FitModel> make_perframe(const FitData& data, const Settings& s, uint64_t) {
    PerframeOptions o;
    apply_settings(s, o);
    return std::make_unique<PerframeModel>(data, o);
}

}  // namespace

const std::vector<PresetInfo>& fit_presets() {
    static const std::vector<PresetInfo> presets = {
        {"fast", "explicit atlas textures and warps; trains in minutes on a CPU", true, make_fast},
        {"paper", "the paper's MLP mappings and deep-image-prior atlases; slow on a CPU", true,
         make_paper},
        {"perframe", "baseline: each frame deconvolved alone (TV MAP), no atlas", false,
         make_perframe},
    };
    return presets;
}

const PresetInfo& find_preset(const std::string& name) {
    for (const auto& p : fit_presets())
        if (p.name == name) return p;
    throw Error("unknown preset '" + name + "' (use " + preset_names(", ") + ")");
}

std::string preset_names(const std::string& sep) {
    std::string s;
    for (const auto& p : fit_presets()) s += (s.empty() ? "" : sep) + p.name;
    return s;
}

std::unique_ptr<FitModel> make_model(const std::string& preset, const FitData& data, uint64_t seed,
                                     const Settings& settings) {
    const PresetInfo& p = find_preset(preset);
    torch::manual_seed(seed);
    return p.make(data, settings, seed);
}

}  // namespace refocus
