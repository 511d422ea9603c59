#pragma once
// Initial circle-of-confusion estimate: the blur radius (px) per pixel of one frame, from the
// edge reblur gradient ratio of Zhuo & Sim 2011 ("Defocus map estimation from a single image"),
// propagated from edges to every pixel with a confidence-weighted guided filter (He, Sun & Tang
// 2013, with the per-window least squares weighted by the edge confidence).
//
// At an edge blurred by a Gaussian of σ, reblurring with a known σ0 changes the gradient
// magnitude by R = |∇I| / |∇(I ⊛ g_σ0)| = sqrt(σ² + σ0²) / σ, so σ = σ0 / sqrt(R² − 1)
// (Zhuo & Sim eq. 4-6).
//
// From σ to the disk radius r. A pillbox of radius r has per-axis variance r²/4 (σ = r/2), but
// the ratio does not measure the variance: it measures the curvature of the edge's line-spread
// function at its peak. For the pillbox the LSF is a half-ellipse ∝ sqrt(r² − x²), whose peak
// falls by σ0²/(2r²) under a small reblur, so the estimator returns σ ≈ r, not r/2; for a
// Gaussian it returns σ = r/2 (second-moment match). The conversion is therefore calibrated per
// PSF model: the estimator (same derivative, same reblur kernel, pixel-integrated edges at
// sub-pixel offsets) is run on 1-D edges of known radius once, and σ → r is read off that
// monotone table (coc_from_sigma). This also removes the bias of the discrete derivative at
// small radii (a perfectly sharp edge measures σ ≈ 0.5 px, which maps to r = 0).
#include <vector>

#include "io/image.h"
#include "prepare/flow.h"

namespace refocus {

enum class CocPsf {
    Disk,      // pillbox / the lens blur layer's disk (default: what real lenses and the fit use)
    Gaussian,  // Gaussian blur of σ, reported as the equal-variance disk radius r = 2σ
};

struct CocOptions {
    CocPsf psf = CocPsf::Disk;
    // Reblur σ (px). Zhuo & Sim use 1; 2 measured better here: at large radii R − 1 is tiny
    // (r = 6 px: R ≈ 1.014 with σ0 = 1, 1.054 with σ0 = 2), so noise and neighbouring edges
    // move the estimate far less.
    double sigma0 = 2.0;
    // Gaussian pre-smoothing σ (px) before the estimate, to keep noise from inflating the edge
    // gradient (which reads as too small a radius); part of the calibration, so unbiased on
    // clean edges.
    double presmooth = 1.0;
    double min_edge_gradient = 0.004;  // linear-light gradient per px an edge needs at least
    double edge_median_factor = 4.0;   // ... and this times the frame's median gradient (noise)
    int guide_radius = 0;              // guided filter window radius; 0 = max(4, min(w, h) / 10)
    double guide_eps = 1e-3;           // guided filter ε on the sRGB grey guide in [0, 1]
    double rmax = 16.0;                // radii are clamped to [0, rmax]
};

// Single-channel radius map (px) of a linear RGB frame.
Image estimate_coc(const Image& frame, const CocOptions& opts = {});

// The sparse step: radius at Canny edge pixels of the frame (other pixels 0) and a weight map
// (1 at accepted edge pixels, 0 elsewhere). For diagnostics and tests.
Image estimate_coc_at_edges(const Image& frame, const CocOptions& opts, Image& weight);

// Calibrated conversion of the ratio estimator's σ (px) to a radius (px) for `psf`, `sigma0`.
double coc_from_sigma(double sigma_est, CocPsf psf, double sigma0, double presmooth = 0.0);
// What the estimator measures on an ideal edge of radius r (the calibration table's forward map).
double sigma_of_coc(double r, CocPsf psf, double sigma0, double presmooth = 0.0);

// Guided filter of He et al. with per-pixel confidence `weight` (1-channel, ≥ 0) in every
// window's least squares: q = mean_k(a_k)·I + mean_k(b_k), window means weighted by the window's
// total confidence. `coverage` (optional) gets that confidence per pixel; pixels with none get 0.
// guide: 1-channel; src: 1-channel; both of one size.
Image weighted_guided_filter(const Image& guide, const Image& src, const Image& weight, int radius,
                             double eps, Image* coverage = nullptr);

// Temporal smoothing with weights (1, 2, 1) over frames t−1, t, t+1, the neighbours' maps
// warped along the consistent flow (pixels failing the consistency test keep fewer taps).
std::vector<Image> smooth_coc_temporally(const std::vector<Image>& coc, const ClipFlow& flow);

}  // namespace refocus
