#pragma once
// Absolute blur of a large defocus from the power spectrum of image tiles, for what is never in
// focus and blurred past what isolated edges measure (edge_blur.h reads such a wall low: at that
// blur its texture sits inside every edge profile's window; docs/method.md, Radius estimation).
//
// The model (seed 001 §1.1.3, the blur as a convolution y = k_r * x + n, with a Gaussian prior
// on x): each tile's windowed periodogram P(f) is distributed as an exponential of mean
//     v_r(f) = |K_r(f)|² · c / |f|^a + s²,
// K_r the optical transfer function of the fit's own kernel at radius r (the lens blur layer:
// a pillbox's transfer function 2·J1(2π|f|r)/(2π|f|r) has zero rings at |f| = 0.61/r, 1.12/r,
// ...), c/|f|^a the image's spectrum (a: `exponents`) and s² white noise (8-bit quantisation).
// The radius is the one of greatest evidence, the negative log-likelihood
//     L(r) = min_{c,s²,a} Σ_f [ P(f) / v_r(f) + log v_r(f) ],
// the Gaussian-prior "MAP_k" of blind deconvolution (the blur marginalised over the image, not
// jointly maximised with it, which favours no blur). Periodogram values are pooled in rings of
// |f| (the kernel is isotropic), and c, s² are fitted per ring profile by Fisher scoring in
// log-parameters. Searched over [rmin, rmax]; a tile whose best radius is at either end of the
// range says nothing and is dropped (a sharp texture's evidence keeps falling toward r = 0). The
// caller uses it only where the blur is known to be large (edges read past floor_max): a tile
// averages the blur over 64x128 px, and small blurs are what edges measure well.
#include <torch/types.h>

#include <vector>

#include "ops/lens_blur.h"

namespace refocus {

struct SpectralBlurOptions {
    // Tile size (px). The first zero ring of a 9.5 px blur is 0.064 cycles/px: 48 rows resolve it
    // in 3 bins, too few, and the evidence then keeps falling toward large radii; 64x128 tiles
    // read it (docs/method.md, Radius estimation; tests/test_spectral_blur.cpp).
    int tile_h = 64, tile_w = 128;
    int stride = 16;                               // tile step (px) ...
    int max_tiles = 160;                           // ... grown to hold at most this many per frame
    int max_width = 480;                           // wider frames are read at 1/k size (below)
    double rmin = 1.0, rmax = 16.0, rstep = 0.25;  // radii searched (px)
    // Window on each axis: Tukey with this share tapered (1: Hann). A partial taper leaks the
    // strong low frequencies into the zero rings, and the reading runs to the end of the range.
    double taper = 1.0;
    int fisher_iters = 25;  // Fisher-scoring iterations for c, s² per radius (converged by 10)
    // The image prior's spectrum c/|f|^a: L is the least over these exponents. Walls of glyphs
    // and stripes fall like |f|^-0.7, not a natural image's |f|^-2, and with a = 2 alone a small
    // radius explains their flat mid frequencies better (docs/method.md, Radius estimation).
    std::vector<double> exponents = {0.5, 1.0, 1.5, 2.0};
};

// Tile readings: centre coordinates (px), radius (px); 1-D float tensors of one length.
struct SpectralBlurSamples {
    torch::Tensor x, y, radius;
    int64_t tiles = 0;  // tiles tested (wholly inside `allowed`)
    int64_t size() const { return radius.defined() ? radius.size(0) : 0; }
};

// luma [H,W] linear light; allowed [H,W] (bool or 0/1): a tile is read only where every pixel is
// allowed. `kernel`: the fit's blur. A frame wider than max_width is area-averaged by the
// integer k that brings it under, read, and its readings (places and radii) scaled by k.
SpectralBlurSamples measure_spectral_blur(const torch::Tensor& luma, const torch::Tensor& allowed,
                                          const LensBlurParams& kernel,
                                          const SpectralBlurOptions& opts = {});

// L(r) of one tile [tile_h, tile_w] for each radius in `radii` (exposed for tests).
torch::Tensor spectral_blur_evidence(const torch::Tensor& tile, const std::vector<double>& radii,
                                     const LensBlurParams& kernel,
                                     const SpectralBlurOptions& opts = {});

}  // namespace refocus
