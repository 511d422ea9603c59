#pragma once
// Image and video quality metrics.
//
// Colour space: like the paper's tables, every metric is computed on sRGB-encoded 8-bit values
// (linear frames are encoded with the sRGB curve, clamped to [0,1] and rounded to 1/255), on the
// R, G and B channels, with peak 255. SSIM is the mean over the three channels of Wang et al.'s
// SSIM (11x11 Gaussian window, sigma 1.5, K1 = 0.01, K2 = 0.03, "valid" region only, as in
// scikit-image's gaussian_weights=True). MS-SSIM is Wang, Simoncelli and Bovik's 5-scale
// product with exponents (0.0448, 0.2856, 0.3001, 0.2363, 0.1333) and 2x2 average
// downsampling; when the image is too small for 5 scales (the window must fit at the coarsest),
// fewer scales are used and their exponents renormalised to sum to 1. tPSNR is the PSNR of
// consecutive-frame differences: MSE over all (pred[t+1]-pred[t]) - (gt[t+1]-gt[t]) values,
// peak 255.
#include <vector>

#include "io/image.h"

namespace refocus {

enum class MetricSpace { Srgb8, Linear };

// Encodes linear RGB to the metric space (sRGB 8-bit levels as floats in [0,255]).
Image to_metric_space(const Image& linear, MetricSpace space = MetricSpace::Srgb8);

// Raw metrics on images already in the metric space, with the given peak.
double mse(const Image& a, const Image& b);
double psnr_from_mse(double mse, double peak);
double ssim_raw(const Image& a, const Image& b, double peak);
double ms_ssim_raw(const Image& a, const Image& b, double peak, int* scales_used = nullptr);

// Linear-light inputs, evaluated in `space` (default sRGB 8-bit, peak 255).
double psnr(const Image& pred, const Image& gt, MetricSpace space = MetricSpace::Srgb8);
double ssim(const Image& pred, const Image& gt, MetricSpace space = MetricSpace::Srgb8);
double ms_ssim(const Image& pred, const Image& gt, MetricSpace space = MetricSpace::Srgb8);
double tpsnr(const std::vector<Image>& pred, const std::vector<Image>& gt,
             MetricSpace space = MetricSpace::Srgb8);

// Mean PSNR / SSIM over a clip (per-frame values averaged; PSNR of identical frames is
// capped at 100 dB so that averages stay finite).
double mean_psnr(const std::vector<Image>& pred, const std::vector<Image>& gt,
                 MetricSpace space = MetricSpace::Srgb8);
double mean_ssim(const std::vector<Image>& pred, const std::vector<Image>& gt,
                 MetricSpace space = MetricSpace::Srgb8);

// PSNR over a region of the frame: the MSE over the R, G, B values of the pixels where `mask`
// (same width and height; its first channel, values as stored) is >= 0.5 (Inside) or < 0.5
// (Outside), in `space`. NaN when the region holds no pixel.
enum class MaskRegion { Inside, Outside };
double masked_psnr(const Image& pred, const Image& gt, const Image& mask, MaskRegion region,
                   MetricSpace space = MetricSpace::Srgb8);

// Where the error lies in spatial frequency. Each frame (and the ground truth) in the metric
// space, each channel less its mean, under a separable Hann window, goes through a 2-D DFT;
// radial frequency |f| in cycles/px (0 to 0.707) is cut at `edges` (ascending, first 0). Per
// band, over all frames and channels: the ground truth's power sum |G|^2, the error's
// sum |P - G|^2, its share of the error over all bands, and the gain Re<P, G> / |G|^2 (1: the
// band came back at full contrast, 0: not at all; the in-phase part of P over G).
struct BandError {
    double lo = 0, hi = 0;
    double gt_power = 0, err_power = 0, err_share = 0, gain = 0;
};
std::vector<BandError> error_by_band(const std::vector<Image>& pred, const std::vector<Image>& gt,
                                     const std::vector<double>& edges,
                                     MetricSpace space = MetricSpace::Srgb8);

}  // namespace refocus
