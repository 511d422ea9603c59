#pragma once
// From a project to the fit's data: frames from the cache, the prepare stage (run once, then
// reused from prep/), radius maps from --coc or the estimate, masks, homographies.
#include <memory>
#include <string>

#include "fit/fit_model.h"
#include "prepare/log.h"
#include "project/project.h"

namespace refocus {

// "pillbox", or what REFOCUS_FIT_KERNEL says (an A/B hook for the benches).
std::string default_fit_kernel();
// The kernel's parameters; throws naming `kernel` when it is neither "pillbox" nor "disk".
LensBlurParams fit_kernel_params(const std::string& kernel);

struct FitSetupOptions {
    std::string coc_path;   // per-frame radius maps (EXR, px); empty: the prepare estimate
    std::string mask_path;  // per-frame masks; empty: automatic
    bool force_prepare = false;
    bool single_image_coc = false;  // radius from the per-frame edge estimator only
    // The lens blur layer's kernel for the fit (FitData::blur): "pillbox" (seed 001 eq. 1.13,
    // the default since the tenth session) or "disk" (paper eq. 2, β = 2; what projects fitted
    // by earlier builds used, kept for them: read_fit_settings).
    std::string kernel = default_fit_kernel();
};

// Sets d.atlas_scale for the fast preset from the radius's source (given with --coc or
// estimated), the camera and how much of the clip is in focus (2: a 2x atlas that resolves
// detail seen at many sub-pixel phases); returns the log line. REFOCUS_FAST_ATLAS_SCALE
// overrides it (A/B hook).
std::string choose_atlas_scale(FitData& d, bool radius_given);

std::shared_ptr<FitData> build_fit_data(const Project& project, const FitSetupOptions& opts,
                                        PrepareLog& log);

}  // namespace refocus
