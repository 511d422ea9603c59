#include "fit/fit_setup.h"

#include <torch/torch.h>

#include "fit/tensor_image.h"
#include "prepare/prepare.h"
#include "util/error.h"

namespace refocus {

std::shared_ptr<FitData> build_fit_data(const Project& project, const FitSetupOptions& opts,
                                        PrepareLog& log) {
    std::vector<Image> frames;
    frames.reserve(project.frames);
    for (int t = 0; t < project.frames; ++t) frames.push_back(project.read_frame(t));

    PrepareResult prep;
    bool reuse = !opts.force_prepare && has_prepare(project);
    if (reuse) {
        prep = load_prepare(project);
        // Reuse only what was prepared for the same masks and with a radius estimate if needed.
        const std::string want_masks = opts.mask_path.empty() ? "auto" : opts.mask_path;
        if (prep.mask_source != want_masks || (opts.coc_path.empty() && prep.coc.empty()))
            reuse = false;
        else
            log.info("prepare: reusing " + prepare_dir(project));
    }
    if (!reuse) {
        PrepareOptions po;
        po.mask_path = opts.mask_path;
        po.estimate_coc = opts.coc_path.empty();
        prep = prepare_clip(frames, po, log);
        save_prepare(project, prep);
    }

    auto d = std::make_shared<FitData>();
    d->frames = project.frames;
    d->height = project.height;
    d->width = project.width;
    d->input = stack_images(frames);
    std::vector<Image> radius;
    if (!opts.coc_path.empty()) {
        radius = load_coc_maps(opts.coc_path, project.frames, project.width, project.height);
        log.info("radius: given per frame by " + opts.coc_path);
    } else {
        radius = prep.coc;
        log.info("radius: estimated per frame (edge reblur ratio, guided filter)");
    }
    d->radius = stack_images(radius).squeeze(1).contiguous();
    std::vector<torch::Tensor> hs;
    for (const auto& h : prep.motion.to_reference)
        hs.push_back(torch::tensor(std::vector<double>(h.m.begin(), h.m.end()), torch::kFloat64).view({3, 3}));
    d->to_ref = torch::stack(hs);
    d->static_camera = prep.decisions.static_camera;
    d->has_subject = prep.decisions.has_subject && !prep.masks.empty();
    if (d->has_subject) d->mask = stack_images(prep.masks);
    log.info(std::string("fit: ") + (d->static_camera ? "static camera, no learned background warp"
                                                      : "moving camera, learned residual warp") +
             ", " + (d->has_subject ? "two layers (moving subject)" : "one layer (no moving subject)"));
    return d;
}

}  // namespace refocus
