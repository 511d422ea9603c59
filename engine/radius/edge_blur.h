#pragma once
// Absolute blur from a single image, at its edges: the luma profile across an edge, averaged
// along it, is the step response (edge spread function) of the blur at that point. Each edge's
// profile is fitted by a + b·ESF_r(s − s0), where ESF_r is the fit's own kernel (the lens blur
// layer, seed 001 eq. 1.13 for the pillbox) applied to a pixel-integrated step at sub-pixel
// offset s0, over a window of r + pad px on either side of the edge; the radius is the r whose
// least-squares fit leaves the smallest residual relative to the step's contrast b², and an
// edge counts only where that residual is small (an isolated step: texture, lines and corners
// do not look like one) and the step is strong.
//
// Why: the focal stack (stack_coc.h) measures blur relative to the sharpest view of each point,
// so what a clip never shows in focus reads 0 (a focus puller's miss: the synth pan clip's
// subject, blurred in every frame, and its wall under a fixed focus). This measures what the
// sharpest view itself still holds. It is unbiased on isolated edges of a few px; on a wall
// blurred past ~4 px with dense texture it reads low, as a blurred bump's flank looks like a
// narrower step (spectral_blur.h; docs/method.md, Radius estimation). Radii are in the kernel's
// units, like the stack's.
#include <torch/types.h>

#include "ops/lens_blur.h"

namespace refocus {

struct EdgeBlurOptions {
    double sigma = 1.0;  // Gaussian derivative scale of the edge detector (px)
    int along = 3;       // the profile is averaged over ±along px along the edge
    int reach = 16;      // ... and sampled over ±reach px across it
    double rmax = 12.0;  // radii tested: 0, rstep, ..., rmax (px)
    double rstep = 0.25;
    double pad = 3.5;            // fit window: |s − s0| ≤ r + pad
    double max_residual = 6e-4;  // mean squared residual / b² an accepted edge stays under
    double min_contrast = 0.03;  // linear-light luma step an accepted edge has at least
    double edge_quantile = 0.7;  // candidates: gradient maxima above this quantile of |∇|
    int max_candidates = 40000;  // more are subsampled evenly (deterministic)
};

// Accepted edges: pixel coordinates, radius (px), residual; 1-D tensors of one length.
struct EdgeBlurSamples {
    torch::Tensor x, y, radius, residual;
    int64_t candidates = 0;  // edges tested
    int64_t size() const { return radius.defined() ? radius.size(0) : 0; }
};

// luma [H,W] (linear light); allowed [H,W] (bool or 0/1): where an edge may be measured; every
// sample of its profile must lie where allowed is set, too. `kernel`: the fit's blur.
EdgeBlurSamples measure_edge_blur(const torch::Tensor& luma, const torch::Tensor& allowed,
                                  const LensBlurParams& kernel, const EdgeBlurOptions& opts = {});

// The model's step responses, [K, 2·reach + 1] for radii × offsets (row k: radius
// radii[k / offsets], offset offsets[k % offsets]); exposed for tests.
torch::Tensor edge_spread_table(const LensBlurParams& kernel, const EdgeBlurOptions& opts,
                                std::vector<double>* radii = nullptr,
                                std::vector<double>* offsets = nullptr);

}  // namespace refocus
