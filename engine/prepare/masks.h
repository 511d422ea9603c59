#pragma once
// Foreground masks: 1 on the moving subject (the foreground layer), 0 on the background.
// Either given by the user (one image per frame) or found automatically.
//
// Automatic masks (seed 001 §1.5.1: "register with a homography, threshold the residual, close
// it"), adapted to defocused video. Seed 001 thresholds the intensity difference of the
// registered frames; here focus changes from frame to frame too, which makes every edge differ
// after registration, and a flat subject only differs along its outline. So the residual is the
// flow's: how far each pixel's optical flow departs from the flow the camera homography
// predicts. Defocus barely moves features, so that residual is the subject's own motion. Per
// frame it takes the smaller residual of the forward (t → t+1) and backward (t → t−1) flows among
// the directions that pass the consistency test (occluded background is inconsistent in one
// direction only; pixels inconsistent both ways count as background), thresholds it robustly
// (median + k·1.4826·MAD, floored at min_residual_px), closes, fills holes, opens and keeps
// components of significant area. Limit: a subject moving less than min_residual_px per frame
// relative to the background is not separated (it is, for the fit, part of the rigid background).
#include <string>
#include <vector>

#include "io/image.h"
#include "prepare/flow.h"
#include "prepare/motion.h"

namespace refocus {

struct MaskOptions {
    double k_mad = 6.0;             // robust threshold: median + k·1.4826·MAD of the residual
    double min_residual_px = 0.75;  // ... but never below this (px per frame)
    int close_px = 3;               // closing radius (bridges gaps in the residual)
    int open_px = 1;                // opening radius (removes specks)
    bool fill_holes = true;         // flat subject interiors have little flow residual
    double min_area_frac = 0.002;   // keep components covering at least this share of the frame
};

// Per-frame flow residual (px), single channel, as described above.
std::vector<Image> flow_residuals(const ClipFlow& flow, const CameraMotion& motion, int width,
                                  int height);

// Automatic masks from the residuals: single-channel 0/1 images.
std::vector<Image> auto_masks(const std::vector<Image>& residuals, const MaskOptions& opts = {});

// User masks: `path` is a printf pattern (masks/mask_%04d.png, numbered from 0 or 1), a folder
// of images (natural order) or, for a one-frame clip, one image. Exactly `frames` images of
// width x height are required; errors name the offending file. Grey and RGB masks use their
// mean, RGBA masks their alpha; values are taken as stored (no sRGB decode), clamped to [0,1].
std::vector<Image> load_masks(const std::string& path, int frames, int width, int height);

// Radius maps (px) for `refocus fit --coc`: single-channel (or first channel) float images,
// finite and ≥ 0, same rules for count and size as load_masks.
std::vector<Image> load_coc_maps(const std::string& path, int frames, int width, int height);

}  // namespace refocus
