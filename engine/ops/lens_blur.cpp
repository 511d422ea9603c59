// The lens blur layer (paper §3.3, eq. 2 and 3), fast path: hand-written forward (scatter) and
// backward (gather) loops wrapped in a torch::autograd::Function. Conventions (support, edge
// subtraction, border rule, small-radius blend) are stated in lens_blur.h; the slow reference
// in lens_blur_reference.cpp implements the same definitions independently.
//
// Notation: source pixel p with radius r, tap offset δ, kernel k̃(δ; r) ≥ 0, in-image tap set
// T_p, S = Σ_{δ∈T_p} k̃, blend s = s(r). The operator is
//   out[p+δ] += x[p]·(s·k̃(δ)/S + (1 − s)·[δ = 0]).
// Its adjoint (the image gradient, seed 001 eq. 1.9) gathers the same taps:
//   g_x[p] = (1 − s)·g[p] + (s/S)·Σ_δ k̃(δ)·g[p+δ],
// and the radius gradient, with S' = Σ ∂k̃/∂r, B = Σ (∂k̃/∂r)·g[p+δ], A = Σ k̃·g[p+δ]:
//   g_r[p] = Σ_c x_c[p]·( s'·(A_c/S − g_c[p]) + s·(B_c − (S'/S)·A_c)/S ).
// Both loops visit each source pixel's own taps only, so the backward needs no atomics; the
// forward scatters into one buffer per thread, summed at the end.
#include "ops/lens_blur.h"

#include <ATen/Parallel.h>
#include <omp.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <vector>

#include "util/error.h"

namespace refocus {

namespace {

constexpr int kTile = 32;  // tiles of kTile × kTile source pixels are the unit of work

double disk_tail(double beta) { return std::max(kDiskTail / beta, kDiskTailMin); }

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

struct Tile {
    int y0, y1, x0, x1;
    bool identity;  // every pixel at r ≤ min_radius: nothing to blur
};

template <typename T>
std::vector<Tile> make_tiles(const T* rad, int H, int W, double rmin) {
    std::vector<Tile> tiles;
    for (int ty = 0; ty < H; ty += kTile) {
        for (int tx = 0; tx < W; tx += kTile) {
            Tile t{ty, std::min(ty + kTile, H), tx, std::min(tx + kTile, W), true};
            for (int y = t.y0; y < t.y1 && t.identity; ++y)
                for (int x = t.x0; x < t.x1; ++x)
                    if (rad[static_cast<size_t>(y) * W + x] > rmin) {
                        t.identity = false;
                        break;
                    }
            tiles.push_back(t);
        }
    }
    return tiles;
}

int num_threads() { return std::max(1, at::get_num_threads()); }

// ---- forward: scatter ----
// CC is the channel count when known at compile time (1 or 3), 0 for any.
template <typename T, int CC>
void forward_hwc(const T* img, const T* rad, T* out, int C, int H, int W,
                 const LensBlurParams& params) {
    const int nc = CC > 0 ? CC : C;
    const size_t plane = static_cast<size_t>(H) * W * nc;
    const std::vector<Tile> tiles = make_tiles(rad, H, W, params.min_radius);
    const int nt = std::min<int>(num_threads(), static_cast<int>(tiles.size()));
    std::vector<std::vector<T>> extra(std::max(0, nt - 1));
    std::fill(out, out + plane, T(0));
    const int max_extent = std::max(H, W);

#pragma omp parallel num_threads(nt)
    {
        const int tid = omp_get_thread_num();
        const int team = omp_get_num_threads();  // may be fewer than nt
        T* buf = out;
        if (tid > 0) {
            extra[tid - 1].assign(plane, T(0));
            buf = extra[tid - 1].data();
        }
        KernelEval ev(params);
        constexpr int kRep = CC == 3 ? 3 : 1;
        KernelTable<T, kRep> tab;
        std::vector<T> v(nc), v3;
        // Static round-robin, not dynamic: which buffer a tile lands in must not depend on
        // timing, or float rounding differs run to run and a fit is not reproducible per seed.
#pragma omp for schedule(static, 1)
        for (size_t ti = 0; ti < tiles.size(); ++ti) {
            const Tile& t = tiles[ti];
            for (int py = t.y0; py < t.y1; ++py) {
                for (int px = t.x0; px < t.x1; ++px) {
                    const size_t p = static_cast<size_t>(py) * W + px;
                    const T* ip = img + p * nc;
                    T* op = buf + p * nc;
                    const double r = rad[p];
                    if (t.identity || r <= params.min_radius) {
                        for (int c = 0; c < nc; ++c) op[c] += ip[c];
                        continue;
                    }
                    double s, ds;
                    blend(r, params.min_radius, s, ds);
                    ev.set_radius(r);
                    tab.build(ev, r, max_extent, false);
                    const int R = tab.R;
                    const int ya = std::max(-R, -py), yb = std::min(R, H - 1 - py);
                    const bool clipped = py - R < 0 || py + R >= H || px - R < 0 || px + R >= W;
                    double S = tab.sum;
                    if (clipped) {  // border rule: normalise over the in-image taps
                        S = 0;
                        for (int y = ya; y <= yb; ++y) {
                            const int X = tab.span[std::abs(y)];
                            const int xa = std::max(-X, -px), xb = std::min(X, W - 1 - px);
                            const T* kr = tab.row(std::abs(y));
                            for (int x = xa; x <= xb; ++x) S += kr[x * kRep];
                        }
                    }
                    const double a = s / S;
                    for (int c = 0; c < nc; ++c) v[c] = static_cast<T>(ip[c] * a);
                    if constexpr (CC == 3) {  // the colour repeated along a row: v0 v1 v2 v0 …
                        v3.resize(3 * (2 * R + 1));
                        for (size_t j = 0; j < v3.size(); ++j) v3[j] = v[j % 3];
                    }
                    for (int y = ya; y <= yb; ++y) {
                        const int X = tab.span[std::abs(y)];
                        if (X < 0) continue;
                        const int xa = std::max(-X, -px), xb = std::min(X, W - 1 - px);
                        const T* kr = tab.row(std::abs(y));
                        T* orow = buf + (static_cast<size_t>(py + y) * W + px) * nc;
                        if constexpr (CC == 3) {
                            T* __restrict o = orow + 3 * xa;
                            const T* __restrict w = kr + 3 * xa;
                            const T* __restrict vv = v3.data();
                            const int n = 3 * (xb - xa + 1);
#pragma omp simd
                            for (int j = 0; j < n; ++j) o[j] += w[j] * vv[j];
                        } else {
                            for (int x = xa; x <= xb; ++x) {
                                const T w = kr[x];
                                for (int c = 0; c < nc; ++c) orow[x * nc + c] += w * v[c];
                            }
                        }
                    }
                    if (s < 1)
                        for (int c = 0; c < nc; ++c) op[c] += static_cast<T>((1 - s) * ip[c]);
                }
            }
        }
        // Sum the per-thread buffers into out, split by element range.
#pragma omp for schedule(static)
        for (size_t i = 0; i < plane; ++i)
            for (int b = 0; b < team - 1; ++b) out[i] += extra[b][i];
    }
}

// ---- backward: gather ----
// grad_out, img in HWC; writes gimg (HWC, if non-null) and grad (H·W, if non-null).
template <typename T, int CC>
void backward_hwc(const T* gout, const T* img, const T* rad, T* gimg, T* grad, int C, int H,
                  int W, const LensBlurParams& params) {
    const int nc = CC > 0 ? CC : C;
    const std::vector<Tile> tiles = make_tiles(rad, H, W, params.min_radius);
    const int nt = std::min<int>(num_threads(), static_cast<int>(tiles.size()));
    const int max_extent = std::max(H, W);
    const bool want_r = grad != nullptr;

#pragma omp parallel num_threads(nt)
    {
        KernelEval ev(params);
        constexpr int kRep = CC == 3 ? 3 : 1;
        KernelTable<T, kRep> tab;
        std::vector<T> acc(nc), bcc(nc);
#pragma omp for schedule(dynamic, 1)
        for (size_t ti = 0; ti < tiles.size(); ++ti) {
            const Tile& t = tiles[ti];
            for (int py = t.y0; py < t.y1; ++py) {
                for (int px = t.x0; px < t.x1; ++px) {
                    const size_t p = static_cast<size_t>(py) * W + px;
                    const T* gp = gout + p * nc;
                    const double r = rad[p];
                    if (t.identity || r <= params.min_radius) {
                        if (gimg)
                            for (int c = 0; c < nc; ++c) gimg[p * nc + c] = gp[c];
                        if (want_r) grad[p] = 0;
                        continue;
                    }
                    double s, ds;
                    blend(r, params.min_radius, s, ds);
                    ev.set_radius(r);
                    tab.build(ev, r, max_extent, want_r);
                    const int R = tab.R;
                    const int ya = std::max(-R, -py), yb = std::min(R, H - 1 - py);
                    T S = 0, Sd = 0;
                    std::fill(acc.begin(), acc.end(), T(0));
                    std::fill(bcc.begin(), bcc.end(), T(0));
                    for (int y = ya; y <= yb; ++y) {
                        const int X = tab.span[std::abs(y)];
                        if (X < 0) continue;
                        const int xa = std::max(-X, -px), xb = std::min(X, W - 1 - px);
                        const T* kr = tab.row(std::abs(y));
                        const T* grow = gout + (static_cast<size_t>(py + y) * W + px) * nc;
                        if constexpr (CC == 3) {
                            // Contiguous over the row's 3·n floats; 12 lanes (a multiple of 3
                            // and of the SIMD width), lane u holds channel u % 3.
                            const T* __restrict w = kr + 3 * xa;
                            const T* __restrict gg = grow + 3 * xa;
                            const int n = 3 * (xb - xa + 1);
                            T a12[12] = {}, b12[12] = {}, s12[12] = {}, d12[12] = {};
                            int j = 0;
                            if (!want_r) {
                                for (; j + 12 <= n; j += 12)
                                    for (int u = 0; u < 12; ++u) {
                                        s12[u] += w[j + u];
                                        a12[u] += w[j + u] * gg[j + u];
                                    }
                                for (; j < n; j += 3) {  // whole taps left over
                                    S += w[j];
                                    acc[0] += w[j] * gg[j];
                                    acc[1] += w[j] * gg[j + 1];
                                    acc[2] += w[j] * gg[j + 2];
                                }
                            } else {
                                const T* __restrict dw = tab.drow(std::abs(y)) + 3 * xa;
                                for (; j + 12 <= n; j += 12)
                                    for (int u = 0; u < 12; ++u) {
                                        s12[u] += w[j + u];
                                        d12[u] += dw[j + u];
                                        a12[u] += w[j + u] * gg[j + u];
                                        b12[u] += dw[j + u] * gg[j + u];
                                    }
                                for (; j < n; j += 3) {  // whole taps left over
                                    S += w[j];
                                    Sd += dw[j];
                                    for (int c = 0; c < 3; ++c) {
                                        acc[c] += w[j] * gg[j + c];
                                        bcc[c] += dw[j] * gg[j + c];
                                    }
                                }
                            }
                            T s_all = 0, d_all = 0;
                            for (int u = 0; u < 12; ++u) {
                                acc[u % 3] += a12[u];
                                bcc[u % 3] += b12[u];
                                s_all += s12[u];
                                d_all += d12[u];
                            }
                            S += s_all / 3;  // each tap was counted once per channel
                            Sd += d_all / 3;
                        } else if (!want_r) {
                            for (int x = xa; x <= xb; ++x) {
                                const T w = kr[x];
                                S += w;
                                for (int c = 0; c < nc; ++c) acc[c] += w * grow[x * nc + c];
                            }
                        } else {
                            const T* dr = tab.drow(std::abs(y));
                            for (int x = xa; x <= xb; ++x) {
                                const T w = kr[x], dw = dr[x];
                                S += w;
                                Sd += dw;
                                for (int c = 0; c < nc; ++c) {
                                    acc[c] += w * grow[x * nc + c];
                                    bcc[c] += dw * grow[x * nc + c];
                                }
                            }
                        }
                    }
                    const double invS = 1.0 / S;
                    if (gimg)
                        for (int c = 0; c < nc; ++c)
                            gimg[p * nc + c] = static_cast<T>((1 - s) * gp[c] + s * acc[c] * invS);
                    if (want_r) {
                        const T* ip = img + p * nc;
                        double gr = 0;
                        for (int c = 0; c < nc; ++c) {
                            const double A = acc[c] * invS;
                            gr += ip[c] * (ds * (A - gp[c]) + s * (bcc[c] - Sd * A) * invS);
                        }
                        grad[p] = static_cast<T>(gr);
                    }
                }
            }
        }
    }
}

template <typename T, typename F0, typename F1, typename F3>
void dispatch_channels(int C, F0&& any, F1&& one, F3&& three) {
    if (C == 3) three();
    else if (C == 1) one();
    else any();
}

// ---- validation ----
std::string where(int64_t i, int64_t C, int64_t H, int64_t W, bool has_channels) {
    std::ostringstream os;
    int64_t hw = H * W;
    if (has_channels) os << "channel " << i / hw << ", ";
    os << "pixel (x " << (i % hw) % W << ", y " << (i % hw) / W << ")";
    return os.str();
}

template <typename T>
void check_finite(const torch::Tensor& t, const char* what, bool nonneg) {
    const T* d = t.data_ptr<T>();
    const int64_t n = t.numel();
    bool has_c = t.dim() == 3;
    int64_t C = has_c ? t.size(0) : 1, H = t.size(-2), W = t.size(-1);
    for (int64_t i = 0; i < n; ++i) {
        const T v = d[i];
        if (!std::isfinite(v)) {
            std::ostringstream os;
            os << "lens_blur: " << what << " holds a non-finite value (" << v << ") at "
               << where(i, C, H, W, has_c) << "; clean the input first";
            throw Error(os.str());
        }
        if (nonneg && v < 0) {
            std::ostringstream os;
            os << "lens_blur: " << what << " must be >= 0 px, got " << v << " at "
               << where(i, C, H, W, has_c);
            throw Error(os.str());
        }
    }
}

void check_inputs(const torch::Tensor& image, const torch::Tensor& radius, const char* name) {
    if (!image.defined() || !radius.defined()) throw Error("lens_blur: undefined tensor");
    if (image.dim() != 3)
        throw Error(std::string("lens_blur: ") + name + " must be [C,H,W], got " +
                    std::to_string(image.dim()) + " dims");
    if (radius.dim() != 2 || radius.size(0) != image.size(1) || radius.size(1) != image.size(2)) {
        std::ostringstream os;
        os << "lens_blur: radius must be [H,W] = [" << image.size(1) << "," << image.size(2)
           << "], got " << radius.sizes();
        throw Error(os.str());
    }
    if (!image.device().is_cpu() || !radius.device().is_cpu())
        throw Error("lens_blur: tensors must be on the CPU");
    auto st = image.scalar_type();
    if (st != torch::kFloat && st != torch::kDouble)
        throw Error("lens_blur: image must be float32 or float64");
    if (radius.scalar_type() != st)
        throw Error("lens_blur: radius must have the image's dtype");
    if (image.size(0) < 1 || image.size(1) < 1 || image.size(2) < 1)
        throw Error("lens_blur: empty image");
}

void check_values(const torch::Tensor& image, const torch::Tensor& radius, const char* name) {
    if (image.scalar_type() == torch::kFloat) {
        check_finite<float>(image, name, false);
        check_finite<float>(radius, "radius", true);
    } else {
        check_finite<double>(image, name, false);
        check_finite<double>(radius, "radius", true);
    }
}

torch::Tensor to_hwc(const torch::Tensor& chw) { return chw.permute({1, 2, 0}).contiguous(); }
torch::Tensor to_chw(const torch::Tensor& hwc) { return hwc.permute({2, 0, 1}).contiguous(); }

torch::Tensor run_forward(const torch::Tensor& image, const torch::Tensor& radius,
                          const LensBlurParams& params) {
    const int C = image.size(0), H = image.size(1), W = image.size(2);
    torch::Tensor img = to_hwc(image);
    torch::Tensor rad = radius.contiguous();
    torch::Tensor out = torch::empty_like(img);
    AT_DISPATCH_FLOATING_TYPES(image.scalar_type(), "lens_blur_forward", [&] {
        const auto* ip = img.data_ptr<scalar_t>();
        const auto* rp = rad.data_ptr<scalar_t>();
        auto* op = out.data_ptr<scalar_t>();
        dispatch_channels<scalar_t>(
            C, [&] { forward_hwc<scalar_t, 0>(ip, rp, op, C, H, W, params); },
            [&] { forward_hwc<scalar_t, 1>(ip, rp, op, C, H, W, params); },
            [&] { forward_hwc<scalar_t, 3>(ip, rp, op, C, H, W, params); });
    });
    return to_chw(out);
}

// Returns {grad_image (or undefined), grad_radius (or undefined)}.
std::pair<torch::Tensor, torch::Tensor> run_backward(const torch::Tensor& grad_out,
                                                     const torch::Tensor& image,
                                                     const torch::Tensor& radius,
                                                     const LensBlurParams& params, bool want_image,
                                                     bool want_radius) {
    const int C = grad_out.size(0), H = grad_out.size(1), W = grad_out.size(2);
    torch::Tensor g = to_hwc(grad_out);
    torch::Tensor img = want_radius ? to_hwc(image) : torch::Tensor();
    torch::Tensor rad = radius.contiguous();
    torch::Tensor gimg = want_image ? torch::empty_like(g) : torch::Tensor();
    torch::Tensor grad = want_radius ? torch::empty_like(rad) : torch::Tensor();
    AT_DISPATCH_FLOATING_TYPES(grad_out.scalar_type(), "lens_blur_backward", [&] {
        const auto* gp = g.data_ptr<scalar_t>();
        const auto* ip = want_radius ? img.data_ptr<scalar_t>() : nullptr;
        const auto* rp = rad.data_ptr<scalar_t>();
        auto* gip = want_image ? gimg.data_ptr<scalar_t>() : nullptr;
        auto* grp = want_radius ? grad.data_ptr<scalar_t>() : nullptr;
        dispatch_channels<scalar_t>(
            C, [&] { backward_hwc<scalar_t, 0>(gp, ip, rp, gip, grp, C, H, W, params); },
            [&] { backward_hwc<scalar_t, 1>(gp, ip, rp, gip, grp, C, H, W, params); },
            [&] { backward_hwc<scalar_t, 3>(gp, ip, rp, gip, grp, C, H, W, params); });
    });
    return {want_image ? to_chw(gimg) : torch::Tensor(), grad};
}

LensBlurParams unpack(torch::autograd::AutogradContext* ctx) {
    LensBlurParams p;
    p.kernel = static_cast<BlurKernel>(ctx->saved_data["kernel"].toInt());
    p.beta = ctx->saved_data["beta"].toDouble();
    p.kappa = ctx->saved_data["kappa"].toDouble();
    p.min_radius = ctx->saved_data["min_radius"].toDouble();
    return p;
}

class LensBlurFunction : public torch::autograd::Function<LensBlurFunction> {
public:
    static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& image,
                                 const torch::Tensor& radius, int64_t kernel, double beta,
                                 double kappa, double min_radius) {
        LensBlurParams p;
        p.kernel = static_cast<BlurKernel>(kernel);
        p.beta = beta;
        p.kappa = kappa;
        p.min_radius = min_radius;
        ctx->saved_data["kernel"] = kernel;
        ctx->saved_data["beta"] = beta;
        ctx->saved_data["kappa"] = kappa;
        ctx->saved_data["min_radius"] = min_radius;
        ctx->save_for_backward({image, radius});
        return run_forward(image, radius, p);
    }

    static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                   torch::autograd::variable_list grads) {
        auto saved = ctx->get_saved_variables();
        const LensBlurParams p = unpack(ctx);
        torch::Tensor g = grads[0];
        const bool want_image = ctx->needs_input_grad(0);
        const bool want_radius = ctx->needs_input_grad(1);
        if (!g.defined() || (!want_image && !want_radius))
            return {torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor(),
                    torch::Tensor(), torch::Tensor()};
        g = g.to(saved[0].scalar_type());
        check_inputs(g, saved[1], "grad_out");
        if (g.scalar_type() == torch::kFloat) check_finite<float>(g.contiguous(), "grad_out", false);
        else check_finite<double>(g.contiguous(), "grad_out", false);
        auto [gi, gr] = run_backward(g, saved[0], saved[1], p, want_image, want_radius);
        return {gi, gr, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
    }
};

}  // namespace

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
        case BlurKernel::Disk: return r + disk_tail(p.beta);
        case BlurKernel::Pillbox: return r + 0.5;
        case BlurKernel::Gaussian: return kGaussianTail * p.kappa * r;
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

torch::Tensor lens_blur(const torch::Tensor& image, const torch::Tensor& radius,
                        const LensBlurParams& params) {
    check_lens_blur_params(params);
    if (!image.defined() || !radius.defined()) throw Error("lens_blur: undefined tensor");
    torch::Tensor rad = radius.scalar_type() == image.scalar_type()
                            ? radius
                            : radius.to(image.scalar_type());
    check_inputs(image, rad, "image");
    {
        torch::NoGradGuard ng;
        check_values(image.contiguous(), rad.contiguous(), "image");
    }
    return LensBlurFunction::apply(image, rad, static_cast<int64_t>(params.kernel), params.beta,
                                   params.kappa, params.min_radius);
}

torch::Tensor lens_blur_adjoint(const torch::Tensor& grad_out, const torch::Tensor& radius,
                                const LensBlurParams& params) {
    check_lens_blur_params(params);
    if (!grad_out.defined() || !radius.defined()) throw Error("lens_blur: undefined tensor");
    torch::NoGradGuard ng;
    torch::Tensor rad = radius.to(grad_out.scalar_type());
    check_inputs(grad_out, rad, "grad_out");
    check_values(grad_out.contiguous(), rad.contiguous(), "grad_out");
    return run_backward(grad_out, torch::Tensor(), rad, params, true, false).first;
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
