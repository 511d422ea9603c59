// The lens blur's kernel as a whole: parameter checks, support, the number of taps the fast
// path visits, and the second moments that convert a physical circle of confusion into a
// kernel radius. The blur itself is in lens_blur.cpp.
#include "ops/lens_blur.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "ops/lens_blur_kernel.h"
#include "util/error.h"

namespace refocus {

using lens_blur_detail::blend;
using lens_blur_detail::disk_tail;
using lens_blur_detail::KernelEval;

void check_lens_blur_params(const LensBlurParams& p) {
    const double inv_e = std::exp(-1.0);
    if (!std::isfinite(p.beta) || !std::isfinite(p.kappa) || !std::isfinite(p.min_radius))
        throw Error("lens_blur: beta, kappa and min_radius must be finite");
    if (p.kernel == BlurKernel::Disk && !(p.beta > inv_e)) {
        std::ostringstream os;
        os << "lens_blur: disk kernel needs beta > 1/e = 0.367879 (paper eq. 2: at beta <= 1/e "
              "the kernel e^{bd}/(e^{bd} - d) stops being positive), got beta = "
           << p.beta;
        throw Error(os.str());
    }
    if (p.kernel == BlurKernel::Gaussian && !(p.kappa > 0))
        throw Error("lens_blur: Gaussian kernel needs kappa > 0 (sigma = kappa * r), got " +
                    std::to_string(p.kappa));
    if (!(p.min_radius >= 0))
        throw Error("lens_blur: min_radius must be >= 0, got " + std::to_string(p.min_radius));
    if (p.kernel != BlurKernel::Disk && p.kernel != BlurKernel::Pillbox &&
        p.kernel != BlurKernel::Gaussian)
        throw Error("lens_blur: unknown kernel");
}

double lens_blur_support(double r, const LensBlurParams& p) {
    if (!(r > p.min_radius)) return 0;
    switch (p.kernel) {
        case BlurKernel::Disk:
            return r + disk_tail(p.beta);
        case BlurKernel::Pillbox:
            return r + 0.5;
        case BlurKernel::Gaussian:
            return kGaussianTail * p.kappa * r;
    }
    return 0;
}

int64_t lens_blur_tap_count(const torch::Tensor& radius, const LensBlurParams& params) {
    check_lens_blur_params(params);
    torch::Tensor rad = radius.to(torch::kDouble).contiguous();
    const int H = rad.size(0), W = rad.size(1);
    const double* r = rad.data_ptr<double>();
    int64_t taps = 0;
    for (int py = 0; py < H; ++py)
        for (int px = 0; px < W; ++px) {
            double rs = lens_blur_support(r[static_cast<size_t>(py) * W + px], params);
            if (rs <= 0) {
                ++taps;
                continue;
            }
            const int R = std::min(static_cast<int>(std::floor(rs)), std::max(H, W));
            for (int y = std::max(-R, -py); y <= std::min(R, H - 1 - py); ++y) {
                double rem = rs * rs - double(y) * y;
                if (rem <= 0) continue;
                int X = std::min(static_cast<int>(std::sqrt(rem)), R);
                while (X >= 0 && double(X) * X + double(y) * y >= rs * rs) --X;
                if (X < 0) continue;
                taps += std::min(X, W - 1 - px) - std::max(-X, -px) + 1;
            }
        }
    return taps;
}

double lens_blur_second_moment(double r, const LensBlurParams& p) {
    check_lens_blur_params(p);
    const double rs = lens_blur_support(r, p);
    if (rs <= 0) return 0;
    KernelEval ke(p);
    ke.set_radius(r);
    const int R = static_cast<int>(std::floor(rs));
    double sum = 0, m2 = 0;
    for (int y = -R; y <= R; ++y)
        for (int x = -R; x <= R; ++x) {
            const double rho2 = double(x) * x + double(y) * y;
            if (rho2 >= rs * rs) continue;
            double k, dk;
            ke.eval(rho2, k, dk);
            sum += k;
            m2 += k * rho2;
        }
    double s, ds;  // the small-radius blend with the identity (header)
    blend(r, p.min_radius, s, ds);
    return sum > 0 ? s * m2 / sum : 0;
}

double coc_second_moment(double coc) {
    if (!(coc > 0)) return 0;
    // Light through the aperture point a lands between pixel centres and is read there by
    // bilinear interpolation, spread over the two nearest pixels of each axis with weights
    // 1 − f and f (f = a − ⌊a⌋): E[ρ²] per axis is a² + f(1 − f). Over the uniform disk, by
    // symmetry twice the one-axis mean under the chord density sqrt(c² − x²): c²/2 plus up to 1/3
    // (the tent's own spread; 0 for a disk that stays inside one pixel).
    const int n = 2000;
    double sum = 0, wsum = 0;
    for (int i = 0; i < n; ++i) {
        const double x = (-1.0 + (2.0 * i + 1.0) / n) * coc;
        const double w = std::sqrt(std::max(0.0, coc * coc - x * x));
        const double f = x - std::floor(x);
        sum += w * (x * x + f * (1.0 - f));
        wsum += w;
    }
    return 2.0 * sum / wsum;
}

double kernel_radius_for_coc(double coc, const LensBlurParams& p) {
    if (!(coc > 0)) return 0;
    // The kernel's moment grows with r; bisect on [0, c + 2] (every kernel here is at least as
    // wide as its radius's disk up to its 1-3 px soft edge).
    const double target = coc_second_moment(coc);
    double lo = 0, hi = coc + 2;
    if (lens_blur_second_moment(hi, p) < target) return hi;
    for (int i = 0; i < 40; ++i) {
        const double mid = 0.5 * (lo + hi);
        (lens_blur_second_moment(mid, p) < target ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi);
}

}  // namespace refocus
