#pragma once
// From a project to the fit's data: frames from the cache, the prepare stage (run once, then
// reused from prep/), radius maps from --coc or the estimate, masks, homographies.
#include <memory>
#include <string>

#include "model/fit_model.h"
#include "fit/settings.h"
#include "prepare/log.h"
#include "project/project.h"

namespace refocus {

// The kernel's parameters; throws naming `kernel` when it is neither "pillbox" nor "disk".
LensBlurParams fit_kernel_params(const std::string& kernel);

struct FitSetupOptions {
    std::string coc_path;   // per-frame radius maps (EXR, px); empty: the prepare estimate
    std::string mask_path;  // per-frame masks; empty: automatic
    bool force_prepare = false;
    bool single_image_coc = false;  // radius from the per-frame edge estimator only
    // The lens blur layer's kernel for the fit (FitData::blur): "pillbox" (seed 001 eq. 1.13)
    // or "disk" (paper eq. 2, β = 2; projects that name no kernel were fitted with it and keep
    // it: read_fit_settings).
    std::string kernel = "pillbox";
    double atlas_scale =
        0;  // the fast preset's atlas texels per frame pixel; 0: choose_atlas_scale
    // Preparation (flow, motion, masks, the radius estimate) runs on frames at most this wide,
    // its results scaled up (prepare/proxy.h); 0: at the clip's size.
    int proxy_width = 640;
    // A clip whose frames (float) exceed this many MB keeps its per-frame arrays in file
    // mappings (util/mapped.h, FitData::mapped_dir).
    double memory_mb = 512;
    // Such a clip keeps its full-size arrays (frames, radius, masks, flow, each layer's radius)
    // in <project>/work/clip/ for the next command to map (model/clip_cache.h).
    bool clip_cache = true;
    Settings settings;  // the radius estimator's (radius.*) and the fields above, as set
};

// Sets d.atlas_scale for the fast preset from the radius's source (given with --coc or
// estimated), the camera and how much of the clip is in focus (2: a 2x atlas that resolves
// detail seen at many sub-pixel phases); returns the log line. `forced` > 0 sets it instead
// (the fast.atlas_scale setting).
std::string choose_atlas_scale(FitData& d, bool radius_given, double forced = 0);

std::shared_ptr<FitData> build_fit_data(const Project& project, const FitSetupOptions& opts,
                                        PrepareLog& log);

}  // namespace refocus
