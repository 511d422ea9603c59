#pragma once
// From a project to the fit's data: frames from the cache, the prepare stage (run once, then
// reused from prep/), radius maps from --coc or the estimate, masks, homographies.
#include <memory>
#include <string>

#include "fit/fit_model.h"
#include "prepare/log.h"
#include "project/project.h"

namespace refocus {

struct FitSetupOptions {
    std::string coc_path;   // per-frame radius maps (EXR, px); empty: the prepare estimate
    std::string mask_path;  // per-frame masks; empty: automatic
    bool force_prepare = false;
    bool single_image_coc = false;  // radius from the per-frame edge estimator only
};

std::shared_ptr<FitData> build_fit_data(const Project& project, const FitSetupOptions& opts,
                                        PrepareLog& log);

}  // namespace refocus
