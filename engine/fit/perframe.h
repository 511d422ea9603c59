#pragma once
// The per-frame baseline (`--preset perframe`): non-blind MAP deconvolution of each frame on
// its own, with the fit's own blur model and radius. Seed 001 §1.1.3: with Gaussian noise the
// MAP estimate minimises eq. 1.5 with one observation (G = H, the lens blur layer) and the
// colour total-variation prior of eq. 1.7,
//     E(u) = ½‖H u − g‖² + λ Σ_px sqrt(|∇u_r|² + |∇u_g|² + |∇u_b|²),
// (the noise variance σ² is folded into λ). Solved by ADMM, the splitting form of the
// half-quadratic approach the seed uses: z = ∇u, scaled dual w, penalty ρ;
//     u ← argmin ½‖Hu − g‖² + ρ/2 ‖∇u − z + w‖²   i.e. (HᵀH + ρ∇ᵀ∇) u = Hᵀg + ρ∇ᵀ(z − w),
//         by a few warm-started conjugate-gradient steps with H = lens_blur, Hᵀ = its adjoint
//         (seed 001 eq. 1.9);
//     z ← vectorial shrinkage of ∇u + w by λ/ρ (the proximal map of eq. 1.7's integrand);
//     w ← w + ∇u − z.
// Every accuracy claim of the product is measured against this baseline, so its defaults
// (λ, ρ, iterations) are tuned for PSNR on textured content at radius 2–8 px.
#include <torch/types.h>

#include <vector>

#include "io/image.h"
#include "ops/lens_blur.h"

namespace refocus {

// λ of eq. 1.7 in linear-light units (image values in [0,1], one unit of gradient per px): the
// best mean sRGB PSNR gain on textured frames blurred 2–8 px by the disk with Gaussian noise of
// σ = 0.005 (≈ 8-bit quantisation plus sensor noise in the mid-tones; docs/method.md, Presets).
// The optimum scales roughly with σ², so pass a smaller λ for clean renders.
constexpr double kDefaultTvLambda = 1e-4;
// ADMM penalty as a multiple of λ when TvDeconvOptions::rho ≤ 0 (affects speed, not the answer).
constexpr double kDefaultRhoPerLambda = 10.0;

struct TvDeconvOptions {
    double lambda = kDefaultTvLambda;  // TV weight (eq. 1.7), linear-light units
    int iterations = 300;              // maximum ADMM iterations
    int cg_iterations = 4;             // CG steps per u-subproblem (warm-started from u)
    double rho = 0.0;                  // ADMM penalty; ≤ 0: kDefaultRhoPerLambda·λ
    double relaxation = 1.6;           // ADMM over-relaxation a ∈ (0, 2); 1 = plain ADMM
    bool precondition = true;          // Fourier preconditioner for the CG (see perframe.cpp)
    LensBlurParams blur{};             // H: the fit's kernel (disk, β = 2) by default
    double tol = 1e-4;                 // stop when ‖u_k − u_{k−1}‖ / ‖u_k‖ < tol
    double sharp_radius = 0.5;         // max radius below this: the frame is returned as is
    bool clamp_output = true;          // linear light is ≥ 0: clamp the result at 0
};

// The perframe preset's deconvolution. λ is for footage, not for clean renders: the blur model
// never matches a lens exactly, and TV absorbs that mismatch; 50 iterations come close to
// convergence at a fifth of the time (docs/method.md, Presets).
struct PerframeOptions {
    double lambda = 0.01;
    int iterations = 50;
};

struct TvDeconvStats {
    int iterations = 0;          // ADMM iterations run
    bool converged = false;      // stopped on tol (not on the iteration cap)
    bool skipped_sharp = false;  // max radius < sharp_radius: nothing done
    double rho = 0.0;            // the penalty used
    double seconds = 0.0;
    int blur_applications = 0;  // calls of lens_blur plus lens_blur_adjoint
    // E(u_k) of eq. 1.5/1.7 for k = 0 (u = g) .. iterations, before the output clamp,
    // and its two terms at the end.
    std::vector<double> objective;
    std::vector<double> rel_change;  // ‖u_k − u_{k−1}‖ / ‖u_k‖, k = 1 .. iterations
    double data_term = 0.0;          // ½‖Hu − g‖²
    double tv_term = 0.0;            // Σ sqrt(|∇u_r|² + |∇u_g|² + |∇u_b|²) (without λ)
};

// blurred [3,H,W] (or [C,H,W]) linear light, float or double; radius [H,W] ≥ 0 in px (the same
// map the blur was made with). Returns u of the same shape and dtype. Throws refocus::Error on
// bad shapes, non-finite or negative radius, non-finite input, bad options, or if the
// iteration ever produces NaN/Inf.
torch::Tensor deconvolve_tv(const torch::Tensor& blurred, const torch::Tensor& radius,
                            const TvDeconvOptions& options = {}, TvDeconvStats* stats = nullptr);

// Colour TV of eq. 1.7 without λ (forward differences, Neumann boundary), for tests and logs.
double colour_tv(const torch::Tensor& image);

// The same on refocus::Image: a linear RGB frame (3 channels) and a 1-channel radius map of the
// same size.
Image deconvolve_frame(const Image& blurred, const Image& radius,
                       const TvDeconvOptions& options = {}, TvDeconvStats* stats = nullptr);

}  // namespace refocus
