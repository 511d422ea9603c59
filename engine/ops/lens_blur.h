#pragma once
// The lens blur layer (paper §3.3, eq. 2 and 3): a per-pixel scatter-sum where every source
// pixel spreads its colour over its own disk of radius r (px), with its kernel normalised to
// unit sum. Differentiable in the image and in the radius. See lens_blur.cpp.
#include <torch/types.h>

#include <cstdint>

namespace refocus {

enum class BlurKernel {
    Disk,      // paper eq. 2: k = e^{βd} / (e^{βd} − d), d = r − sqrt(x²+y²)
    Pillbox,   // seed 001 eq. 1.13: 1/(πr²) inside the circle, 0 outside
    Gaussian,  // seed 001 eq. 1.20: σ = κ·r
};

struct LensBlurParams {
    BlurKernel kernel = BlurKernel::Disk;
    double beta = 2.0;         // disk fall-off; must be > 1/e
    double kappa = 1.2;        // Gaussian σ = κ·r
    double min_radius = 0.25;  // below this a pixel costs one tap (identity)
};

// image [C,H,W] (float or double, linear light), radius [H,W] ≥ 0 in px → [C,H,W].
torch::Tensor lens_blur(const torch::Tensor& image, const torch::Tensor& radius,
                        const LensBlurParams& params = {});

// The adjoint (gather) H* of the blur with a fixed radius map: <H x, y> = <x, H* y>.
torch::Tensor lens_blur_adjoint(const torch::Tensor& grad_out, const torch::Tensor& radius,
                                const LensBlurParams& params = {});

// ---- Conventions shared by the fast path, the reference and the tensor-ops version ----
// Taps sit at integer offsets (x, y); each kernel is sampled at the tap centre, ρ = sqrt(x²+y²).
// Support (taps with ρ < R_s carry weight; the kernel has its edge value subtracted so that it
// reaches 0 continuously at R_s and a tap entering the support causes no jump in r):
//   Disk:     R_s = r + t_e, t_e = max(kDiskTail/β, kDiskTailMin) px outside the edge, where
//             k(−t_e) = 1/(1 + t_e·e^{β t_e}) ≤ 1.7e-3 for every β (8.3e-4 at β = 2, where
//             t_e = 3 px); k̃ = k − k(−t_e). Inside, k → 1.
//   Pillbox:  eq. 1.13 with a one-pixel linear edge, k = clamp(r + ½ − ρ, 0, 1) (pixel coverage),
//             so that it is differentiable in r; R_s = r + ½.
//   Gaussian: R_s = kGaussianTail·σ, k̃ = e^{−ρ²/2σ²} − e^{−kGaussianTail²/2}.
// Normalisation: each source pixel's kernel is divided by its sum over its *in-image* taps, so
// taps falling outside the frame are dropped and no energy leaves the frame (Σ out = Σ in for
// every image, borders included).
// Small radii: with s(r) = smoothstep((r − min_radius)/kBlendWidth), a pixel spreads
//   (1 − s)·δ + s·(normalised kernel).
// So r ≤ min_radius is exactly the identity (one tap, zero radius gradient) and the kernel
// fades in with a C¹ blend over min_radius < r < min_radius + kBlendWidth.
constexpr double kDiskTail = 6.0;
constexpr double kDiskTailMin = 1.5;
constexpr double kGaussianTail = 4.0;
constexpr double kBlendWidth = 0.5;

// Throws refocus::Error unless β > 1/e (disk), κ > 0, min_radius ≥ 0, all finite.
void check_lens_blur_params(const LensBlurParams& params);

// R_s above, in px, for r > min_radius (0 for r ≤ min_radius: one tap).
double lens_blur_support(double r, const LensBlurParams& params);

// The kernel's second moment E[ρ²] (px²) over its taps at radius r, small-radius blend included.
double lens_blur_second_moment(double r, const LensBlurParams& params = {});

// The kernel radius whose kernel spreads light as far (same second moment) as a uniform disk
// of radius `coc` px, a physical circle of confusion (a thin lens, the aperture renderer),
// imaged onto the pixel grid: the disk's light lands between pixel centres and spreads over
// the nearest pixels (bilinearly, as the aperture renderer samples), which adds up to 1/3 px²
// (coc_second_moment); without that term circles of a few px read about 10% small. The paper's
// disk (eq. 2, β = 2) has a soft edge 1-3 px wide, so it is wider than the disk of its radius:
// a 7 px circle of confusion is its r = 6.38.
double kernel_radius_for_coc(double coc, const LensBlurParams& params = {});

// E[ρ²] (px²) of a uniform disk of radius `coc` px imaged onto the pixel grid by bilinear
// interpolation: c²/2 plus the tent's share, which rises from 0 to 1/3 px² by c ≈ 1.
double coc_second_moment(double coc);

// Number of (source pixel, tap) pairs the fast path visits for this radius map (one per pixel
// at r ≤ min_radius). The benchmark divides it by time for taps/s.
int64_t lens_blur_tap_count(const torch::Tensor& radius, const LensBlurParams& params = {});

// Slow, obviously-correct reference: plain loops over pixels and taps in long double with the
// paper's eq. 2 written as printed. Forward only, returns double.
torch::Tensor lens_blur_reference(const torch::Tensor& image, const torch::Tensor& radius,
                                  const LensBlurParams& params = {});

// Straightforward LibTorch tensor-ops version (a window of the maximum support, one fold per
// kernel row), differentiable by LibTorch autograd. For the benchmark's comparison only: it
// costs O(H·W·(2R_max+1)²) time and a lot of memory.
torch::Tensor lens_blur_tensor_ops(const torch::Tensor& image, const torch::Tensor& radius,
                                   const LensBlurParams& params = {});

}  // namespace refocus
