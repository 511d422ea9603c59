#pragma once
// The lens blur's kernel on the pixel grid, shared by the fast path (lens_blur.cpp) and the
// kernel's support, tap count and moments (lens_blur_kernel.cpp). Internal to ops/; the
// conventions are stated in lens_blur.h.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "ops/lens_blur.h"

namespace refocus::lens_blur_detail {

inline double disk_tail(double beta) {
    return std::max(kDiskTail / beta, kDiskTailMin);
}

// Smoothstep blend s(r) and ds/dr (header: "Small radii").
inline void blend(double r, double rmin, double& s, double& ds) {
    double t = (r - rmin) / kBlendWidth;
    if (t <= 0) {
        s = 0;
        ds = 0;
    } else if (t >= 1) {
        s = 1;
        ds = 0;
    } else {
        s = t * t * (3 - 2 * t);
        ds = 6 * t * (1 - t) / kBlendWidth;
    }
}

// Evaluates k̃(ρ; r) and ∂k̃/∂r for one kernel at one radius.
class KernelEval {
  public:
    explicit KernelEval(const LensBlurParams& p) : m_p(p) {
        m_tail = disk_tail(p.beta);
        // k(−t_e) = E/(E + t_e), E = e^{−β t_e} (underflows harmlessly to 0 for large β).
        const double E = std::exp(-p.beta * m_tail);
        m_disk_edge = E / (E + m_tail);
        m_gauss_edge = std::exp(-0.5 * kGaussianTail * kGaussianTail);
    }
    void set_radius(double r) {
        m_r = r;
        m_support = lens_blur_support(r, m_p);
        if (m_p.kernel == BlurKernel::Gaussian) {
            double sigma = m_p.kappa * r;
            m_inv_2s2 = 0.5 / (sigma * sigma);
            m_inv_s2r = 1.0 / (sigma * sigma * r);
        }
    }
    double support() const { return m_support; }
    inline void eval(double rho2, double& k, double& dk) const {
        switch (m_p.kernel) {
            case BlurKernel::Disk: {
                double d = m_r - std::sqrt(rho2);
                if (d <= -m_tail) {
                    k = dk = 0;
                    return;
                }
                // Paper eq. 2 in the form that cannot overflow on either side: for d ≥ 0,
                // k = 1/(1 − d·e^{−βd}); for d < 0, k = E/(E − d) with E = e^{βd} ≤ 1. The
                // denominator is > 0 because β > 1/e. ∂k/∂d = E(1 − βd)/(E − d)², ∂d/∂r = 1.
                double kk, dkk;
                if (d >= 0) {
                    double e = std::exp(-m_p.beta * d);
                    kk = 1.0 / (1.0 - d * e);
                    dkk = kk * kk * e * (1.0 - m_p.beta * d);
                } else {
                    double E = std::exp(m_p.beta * d);
                    double den = 1.0 / (E - d);
                    kk = E * den;
                    dkk = E * (1.0 - m_p.beta * d) * den * den;
                }
                k = kk - m_disk_edge;
                dk = dkk;
                return;
            }
            case BlurKernel::Pillbox: {
                double a = m_r + 0.5 - std::sqrt(rho2);  // pixel coverage of eq. 1.13's disk
                if (a <= 0) {
                    k = dk = 0;
                } else if (a >= 1) {
                    k = 1;
                    dk = 0;
                } else {
                    k = a;
                    dk = 1;
                }
                return;
            }
            case BlurKernel::Gaussian: {
                double q = rho2 * m_inv_2s2;  // ρ²/2σ²
                if (q >= 0.5 * kGaussianTail * kGaussianTail) {
                    k = dk = 0;
                    return;
                }
                double g = std::exp(-q);  // eq. 1.20 up to the constant that S removes
                k = g - m_gauss_edge;
                dk = g * rho2 * m_inv_s2r;  // ∂/∂r of −ρ²/(2κ²r²) is ρ²/(σ²r)
                return;
            }
        }
        k = dk = 0;
    }

  private:
    LensBlurParams m_p;
    double m_tail = 0, m_disk_edge = 0, m_gauss_edge = 0;
    double m_r = 0, m_support = 0, m_inv_2s2 = 0, m_inv_s2r = 0;
};

// One pixel's kernel on its own support: rows |y| ≤ R, each row stored over x ∈ [−R, R] so that
// the tap loops index it directly. Filled from one octant (the kernel depends on ρ only), so
// a table of N taps costs about N/8 kernel evaluations. With Rep = 3 each entry is repeated
// three times (k3[3(x+R)+c]) so that the RGB tap loops run over contiguous memory with no
// stride-3 pattern, which the compiler vectorises. A table is reused while consecutive pixels
// share the same radius (constant regions of a COC map).
template <typename T, int Rep>
struct KernelTable {
    int R = -1;
    int stride = 0;  // (2R+1)·Rep
    double r = -1;
    bool has_dk = false;
    std::vector<int> span;  // span[|y|]: taps at |x| ≤ span, −1 for an empty row
    std::vector<T> k, dk;
    double sum = 0, dsum = 0;  // over the whole (unclipped) support

    const T* row(int ay) const { return k.data() + static_cast<size_t>(ay) * stride + R * Rep; }
    const T* drow(int ay) const { return dk.data() + static_cast<size_t>(ay) * stride + R * Rep; }

    void build(const KernelEval& ev, double radius, int max_extent, bool with_dk) {
        if (radius == r && (has_dk || !with_dk)) return;
        r = radius;
        has_dk = with_dk;
        double rs = ev.support();
        double rs2 = rs * rs;
        R = std::min(static_cast<int>(std::floor(rs)), max_extent);
        stride = (2 * R + 1) * Rep;
        span.assign(R + 1, -1);
        size_t n = static_cast<size_t>(R + 1) * stride;
        if (k.size() < n) k.resize(n);
        if (with_dk && dk.size() < n) dk.resize(n);
        for (int y = 0; y <= R; ++y) {
            double rem = rs2 - double(y) * y;
            if (rem <= 0) break;
            int x = std::min(static_cast<int>(std::sqrt(rem)), R);
            while (x >= 0 && double(x) * x + double(y) * y >= rs2) --x;
            span[y] = x;
        }
        sum = dsum = 0;
        for (int y = 0; y <= R && span[y] >= y; ++y) {
            for (int x = y; x <= span[y]; ++x) {
                double kv, dkv;
                ev.eval(double(x) * x + double(y) * y, kv, dkv);
                double mult = x == 0 ? 1 : (y == 0 || x == y) ? 4 : 8;
                sum += mult * kv;
                dsum += mult * dkv;
                set(y, x, kv, dkv, with_dk);
                set(x, y, kv, dkv, with_dk);
            }
        }
    }

  private:
    inline void set(int ay, int ax, double kv, double dkv, bool with_dk) {
        size_t base = static_cast<size_t>(ay) * stride + R * Rep;
        for (int c = 0; c < Rep; ++c) {
            k[base + ax * Rep + c] = static_cast<T>(kv);
            k[base - ax * Rep + c] = static_cast<T>(kv);
            if (with_dk) {
                dk[base + ax * Rep + c] = static_cast<T>(dkv);
                dk[base - ax * Rep + c] = static_cast<T>(dkv);
            }
        }
    }
};

}  // namespace refocus::lens_blur_detail
