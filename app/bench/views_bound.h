#pragma once
// The sharpest-view bound of a rendered clip (`refocus bench corpus --views`): every pixel of
// frame t taken from the frame that saw its surface sharpest, found with the clip's true depth,
// cameras and radius. It is what a fit gains by carrying detail that some frame recorded into
// the frames that blurred it, with perfect registration and no deconvolution: the ceiling of
// the sharper-view rule (docs/method.md, Confidence and fallback).
#include <filesystem>

namespace refocus {

struct ViewsBound {
    double in_psnr = 0, in_tpsnr = 0;  // the input against the truth (mean over frames)
    // "least": the view with the least radius where it is more than 0.5 px sharper than the
    // frame's own (else the frame's own); "near": the mean of the views within 0.5 px of that
    // one (noise averaged over the views nearly as sharp), the frame's own where it was kept.
    double least_psnr = 0, least_tpsnr = 0, least_worst = 0;  // worst: the lowest frame gain
    double near_psnr = 0, near_tpsnr = 0, near_worst = 0;
    double sharper_share = 0;  // pixels some other frame saw at least 1 px sharper
};

// Reads the clip folder (tools/corpus/README.md: input, sharp, coc and depth of every frame,
// clip.json's camera_world and lens.focal_px; alpha when present). Pixels of the subject
// (alpha ≥ 0.5) keep their own frame: the cameras do not say how the subject moved. A view
// counts where it is inside frame s and its depth there is within 3% of the reprojected one.
// Throws naming the file when one is missing or clip.json lacks the cameras.
ViewsBound sharpest_view_bound(const std::filesystem::path& clip_dir);

}  // namespace refocus
