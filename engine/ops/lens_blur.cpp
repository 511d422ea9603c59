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

#include "ops/lens_blur_kernel.h"
#include "util/error.h"

namespace refocus {

namespace {

using lens_blur_detail::blend;
using lens_blur_detail::KernelEval;
using lens_blur_detail::KernelTable;

constexpr int kTile = 32;  // tiles of kTile × kTile source pixels are the unit of work

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

int num_threads() {
    return std::max(1, at::get_num_threads());
}

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
void backward_hwc(const T* gout, const T* img, const T* rad, T* gimg, T* grad, int C, int H, int W,
                  const LensBlurParams& params) {
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
    if (C == 3)
        three();
    else if (C == 1)
        one();
    else
        any();
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
    if (radius.scalar_type() != st) throw Error("lens_blur: radius must have the image's dtype");
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

torch::Tensor to_hwc(const torch::Tensor& chw) {
    return chw.permute({1, 2, 0}).contiguous();
}
torch::Tensor to_chw(const torch::Tensor& hwc) {
    return hwc.permute({2, 0, 1}).contiguous();
}

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
            return {torch::Tensor(), torch::Tensor(), torch::Tensor(),
                    torch::Tensor(), torch::Tensor(), torch::Tensor()};
        g = g.to(saved[0].scalar_type());
        check_inputs(g, saved[1], "grad_out");
        if (g.scalar_type() == torch::kFloat)
            check_finite<float>(g.contiguous(), "grad_out", false);
        else
            check_finite<double>(g.contiguous(), "grad_out", false);
        auto [gi, gr] = run_backward(g, saved[0], saved[1], p, want_image, want_radius);
        return {gi, gr, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
    }
};

}  // namespace

torch::Tensor lens_blur(const torch::Tensor& image, const torch::Tensor& radius,
                        const LensBlurParams& params) {
    check_lens_blur_params(params);
    if (!image.defined() || !radius.defined()) throw Error("lens_blur: undefined tensor");
    torch::Tensor rad =
        radius.scalar_type() == image.scalar_type() ? radius : radius.to(image.scalar_type());
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

}  // namespace refocus
