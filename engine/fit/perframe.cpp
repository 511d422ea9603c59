#include "fit/perframe.h"

#include <torch/torch.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <optional>
#include <sstream>

#include "util/error.h"

namespace refocus {
namespace {

// Forward differences with a Neumann boundary (the last column / row difference is 0): the
// discrete ∇ of eq. 1.6/1.7. Returns {∂x, ∂y}, each shaped like u.
std::pair<torch::Tensor, torch::Tensor> grad(const torch::Tensor& u) {
    const int64_t h = u.size(1), w = u.size(2);
    auto dx = torch::zeros_like(u), dy = torch::zeros_like(u);
    if (w > 1) dx.narrow(2, 0, w - 1).copy_(u.narrow(2, 1, w - 1) - u.narrow(2, 0, w - 1));
    if (h > 1) dy.narrow(1, 0, h - 1).copy_(u.narrow(1, 1, h - 1) - u.narrow(1, 0, h - 1));
    return {dx, dy};
}

// ∇ᵀ (= −div), the exact adjoint of grad(): <∇u, p> = <u, ∇ᵀp>.
torch::Tensor grad_t(const torch::Tensor& px, const torch::Tensor& py) {
    const int64_t h = px.size(1), w = px.size(2);
    auto out = torch::zeros_like(px);
    if (w > 1) {
        auto p = px.narrow(2, 0, w - 1);
        out.narrow(2, 0, w - 1).sub_(p);
        out.narrow(2, 1, w - 1).add_(p);
    }
    if (h > 1) {
        auto p = py.narrow(1, 0, h - 1);
        out.narrow(1, 0, h - 1).sub_(p);
        out.narrow(1, 1, h - 1).add_(p);
    }
    return out;
}

// Per-pixel magnitude of the colour gradient: sqrt(Σ_c ∂x u_c² + ∂y u_c²), [1,H,W] (eq. 1.7).
torch::Tensor colour_grad_norm(const torch::Tensor& dx, const torch::Tensor& dy) {
    return (dx.square() + dy.square()).sum(0, /*keepdim=*/true).sqrt();
}

double sum_of_products(const torch::Tensor& a, const torch::Tensor& b) {
    return (a * b).sum().item<double>();
}

void require_finite(const torch::Tensor& t, const char* what) {
    if (!torch::isfinite(t).all().item<bool>()) {
        std::ostringstream s;
        s << "deconvolve_tv: " << what << " contains NaN or Inf";
        throw Error(s.str());
    }
}

void check_options(const TvDeconvOptions& o) {
    auto bad = [](const std::string& m) { throw Error("deconvolve_tv: " + m); };
    if (!std::isfinite(o.lambda) || o.lambda < 0) bad("lambda must be finite and >= 0");
    if (o.iterations < 0) bad("iterations must be >= 0");
    if (o.cg_iterations < 1) bad("cg_iterations must be >= 1");
    if (!std::isfinite(o.rho)) bad("rho must be finite");
    if (!(o.relaxation > 0 && o.relaxation < 2)) bad("relaxation must be in (0, 2)");
    if (!std::isfinite(o.tol) || o.tol < 0) bad("tol must be finite and >= 0");
    if (!std::isfinite(o.sharp_radius)) bad("sharp_radius must be finite");
    check_lens_blur_params(o.blur);
}

// ---- Preconditioner for the u-subproblem ----
// CG on A = HᵀH + ρ∇ᵀ∇ converges slowly where H nearly cancels frequencies (the disk's
// spectrum has zeros), so the u-step is preconditioned with the Fourier inverse of A for a
// spatially invariant blur: P_j = (|K̂_j|² + ρ·L̂)⁻¹, with K_j the model's own kernel at radius
// level r_j and L̂ = 4 − 2cos ωx − 2cos ωy the symbol of ∇ᵀ∇ (periodic). A spatially varying
// radius is covered by a few levels blended with per-pixel weights m_j, Σ m_j² = 1:
//     P = Σ_j M_j P_j M_j   (symmetric positive definite, so PCG stays exact).
class Preconditioner {
  public:
    Preconditioner(const torch::Tensor& radius, double rho, const LensBlurParams& blur,
                   int64_t channels) {
        const int64_t h = radius.size(0), w = radius.size(1);
        const auto opts = radius.options();
        const double r_max = radius.max().item<double>();
        // Levels: 0 (identity), then geometric steps of 1.4× from 1 px past the largest radius.
        std::vector<double> levels{0.0};
        for (double r = 1.0; levels.back() < r_max; r *= 1.4) levels.push_back(r);
        const auto wy = torch::arange(h, opts).mul(2 * M_PI / h).cos().view({h, 1});
        const auto wx = torch::arange(w / 2 + 1, opts).mul(2 * M_PI / w).cos().view({1, -1});
        const auto lap = 4.0 - 2.0 * wy - 2.0 * wx;  // [H, W/2+1]
        for (size_t j = 0; j < levels.size(); ++j) {
            // Linear interpolation weights between neighbouring levels, square-rooted.
            torch::Tensor wgt;
            const double r0 = levels[j];
            if (j + 1 < levels.size()) {
                const double r1 = levels[j + 1];
                wgt = (1.0 - (radius - r0).abs() / (r1 - r0)).clamp_min(0.0);
                if (j == 0) wgt = torch::where(radius <= r0, torch::ones_like(radius), wgt);
            } else {
                wgt = torch::where(radius >= r0, torch::ones_like(radius),
                                   (1.0 - (r0 - radius) / (r0 - levels[j - 1])).clamp_min(0.0));
            }
            if (wgt.max().item<double>() <= 0) continue;
            Level lv;
            lv.mask = wgt.sqrt().unsqueeze(0);  // [1,H,W]
            const auto khat = kernel_spectrum(r0, blur, h, w, opts);
            lv.inv_symbol = 1.0 / (khat.square() + rho * lap + 1e-12);
            m_levels.push_back(lv);
        }
    }

    torch::Tensor apply(const torch::Tensor& x) const {
        torch::Tensor out;
        const int64_t h = x.size(1), w = x.size(2);
        for (const auto& lv : m_levels) {
            auto f = torch::fft::rfft2(x * lv.mask);
            auto y = torch::fft::irfft2(f * lv.inv_symbol, c10::IntArrayRef{h, w}) * lv.mask;
            out = out.defined() ? out.add_(y) : y;
        }
        return out;
    }

  private:
    // |K̂| of the lens blur kernel at constant radius r on the periodic H×W grid (real: the
    // kernels are symmetric). The kernel is the model's own: lens_blur of a centred delta.
    static torch::Tensor kernel_spectrum(double r, const LensBlurParams& blur, int64_t h, int64_t w,
                                         const torch::TensorOptions& opts) {
        if (r <= blur.min_radius) return torch::ones({h, w / 2 + 1}, opts);
        const int64_t s = static_cast<int64_t>(std::ceil(lens_blur_support(r, blur))) + 1;
        const int64_t n = 2 * s + 1;
        auto delta = torch::zeros({1, n, n}, opts);
        delta[0][s][s] = 1.0;
        const auto k = lens_blur(delta, torch::full({n, n}, r, opts), blur)[0];
        // Wrap the centred kernel onto the H×W torus (offsets modulo the size).
        auto grid = torch::zeros({h, w}, torch::kFloat64);
        const auto kd = k.to(torch::kFloat64).contiguous();
        auto ga = grid.accessor<double, 2>();
        auto ka = kd.accessor<double, 2>();
        for (int64_t y = 0; y < n; ++y)
            for (int64_t x = 0; x < n; ++x) {
                const int64_t gy = ((y - s) % h + h) % h, gx = ((x - s) % w + w) % w;
                ga[gy][gx] += ka[y][x];
            }
        return torch::real(torch::fft::rfft2(grid)).to(opts.dtype());
    }

    struct Level {
        torch::Tensor mask;        // [1,H,W], m_j
        torch::Tensor inv_symbol;  // [H, W/2+1], 1 / (|K̂_j|² + ρ L̂)
    };
    std::vector<Level> m_levels;
};

}  // namespace

double colour_tv(const torch::Tensor& image) {
    torch::NoGradGuard no_grad;
    auto [dx, dy] = grad(image);
    return colour_grad_norm(dx, dy).sum().item<double>();
}

torch::Tensor deconvolve_tv(const torch::Tensor& blurred, const torch::Tensor& radius,
                            const TvDeconvOptions& options, TvDeconvStats* stats) {
    torch::NoGradGuard no_grad;
    const auto t0 = std::chrono::steady_clock::now();
    check_options(options);
    if (blurred.dim() != 3 || blurred.size(0) < 1 || blurred.size(1) < 1 || blurred.size(2) < 1)
        throw Error("deconvolve_tv: the frame must be [C,H,W], got " +
                    std::to_string(blurred.dim()) + " dimensions");
    if (radius.dim() != 2 || radius.size(0) != blurred.size(1) ||
        radius.size(1) != blurred.size(2)) {
        std::ostringstream s;
        s << "deconvolve_tv: radius map must be [H,W] = [" << blurred.size(1) << ","
          << blurred.size(2) << "], got " << radius.sizes();
        throw Error(s.str());
    }
    if (!blurred.is_floating_point()) throw Error("deconvolve_tv: the frame must be float");
    require_finite(blurred, "the input frame");
    require_finite(radius, "the radius map");
    if (radius.min().item<double>() < 0) throw Error("deconvolve_tv: negative blur radius");

    TvDeconvStats local;
    TvDeconvStats& st = stats ? *stats : local;
    st = TvDeconvStats{};
    auto finish = [&](torch::Tensor out) {
        st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        return out;
    };

    // A frame that is sharp everywhere needs no deconvolution: it is returned as is.
    if (radius.max().item<double>() < options.sharp_radius || options.iterations == 0) {
        st.skipped_sharp = radius.max().item<double>() < options.sharp_radius;
        return finish(blurred.clone());
    }

    const auto g = blurred.contiguous();
    const auto r = radius.to(g.scalar_type()).contiguous();
    const double lambda = options.lambda;
    const double rho =
        options.rho > 0 ? options.rho : std::max(kDefaultRhoPerLambda * lambda, 1e-6);
    st.rho = rho;
    auto H = [&](const torch::Tensor& x) {
        ++st.blur_applications;
        return lens_blur(x, r, options.blur);
    };
    auto Ht = [&](const torch::Tensor& y) {
        ++st.blur_applications;
        return lens_blur_adjoint(y, r, options.blur);
    };

    // State. u starts at g; Hu and HᵀHu are carried along the CG updates (u += αp implies
    // Hu += αHp, HᵀHu += αHᵀHp), so each CG step costs exactly one H and one Hᵀ and the data
    // term of the objective comes for free.
    auto u = g.clone();
    auto Hu = H(u);
    auto HtHu = Ht(Hu);
    const auto Htg = Ht(g);
    auto [zx, zy] = grad(u);
    auto wx = torch::zeros_like(u), wy = torch::zeros_like(u);

    auto objective = [&](const torch::Tensor& dx, const torch::Tensor& dy, double* data,
                         double* tv) {
        *data = 0.5 * (Hu - g).square().sum().item<double>();
        *tv = colour_grad_norm(dx, dy).sum().item<double>();
        return *data + lambda * *tv;
    };
    {
        double data = 0, tv = 0;
        st.objective.push_back(objective(zx, zy, &data, &tv));
    }

    std::optional<Preconditioner> precond;
    if (options.precondition) precond.emplace(r, rho, options.blur, g.size(0));
    const double thresh = lambda / rho;
    for (int it = 0; it < options.iterations; ++it) {
        const auto u_prev = u.clone();
        // u-step: (HᵀH + ρ∇ᵀ∇) u = Hᵀg + ρ∇ᵀ(z − w), CG warm-started at the current u.
        const auto b = Htg + rho * grad_t(zx - wx, zy - wy);
        auto [gx, gy] = grad(u);
        auto res = b - (HtHu + rho * grad_t(gx, gy));
        const double b_norm2 = sum_of_products(b, b);
        auto zr = precond ? precond->apply(res) : res;
        auto p = zr.clone();
        double rz = sum_of_products(res, zr);
        for (int k = 0; k < options.cg_iterations; ++k) {
            if (sum_of_products(res, res) <= 1e-20 * b_norm2 || !(rz > 0)) break;
            const auto Hp = H(p);
            const auto HtHp = Ht(Hp);
            auto [px, py] = grad(p);
            const auto Ap = HtHp + rho * grad_t(px, py);
            const double pAp = sum_of_products(p, Ap);
            if (!(pAp > 0)) break;  // A is SPD; a non-positive curvature means p ≈ 0
            const double alpha = rz / pAp;
            u.add_(p, alpha);
            Hu.add_(Hp, alpha);
            HtHu.add_(HtHp, alpha);
            res.sub_(Ap, alpha);
            if (k + 1 == options.cg_iterations) break;
            zr = precond ? precond->apply(res) : res;
            const double rz_new = sum_of_products(res, zr);
            p = zr + (rz_new / rz) * p;
            rz = rz_new;
        }
        // z-step: vectorial (colour, isotropic) shrinkage, the prox of λ/ρ·sqrt(Σ_c|∇u_c|²).
        // Over-relaxation (Boyd et al. 2011, §3.4.3): ∇u is replaced by a∇u + (1 − a)z in the
        // z- and w-steps; a ∈ [1.5, 1.8] typically speeds ADMM up with the same fixed point.
        std::tie(gx, gy) = grad(u);
        const double a = options.relaxation;
        const auto vx = a * gx + (1 - a) * zx + wx, vy = a * gy + (1 - a) * zy + wy;
        const auto mag = colour_grad_norm(vx, vy);
        const auto scale = (1.0 - thresh / mag.clamp_min(1e-12)).clamp_min(0.0);
        zx = vx * scale;
        zy = vy * scale;
        // w-step: scaled dual ascent on the constraint z = ∇u.
        wx = vx - zx;
        wy = vy - zy;

        double data = 0, tv = 0;
        const double e = objective(gx, gy, &data, &tv);
        if (!std::isfinite(e)) {
            std::ostringstream s;
            s << "deconvolve_tv: the objective became " << e << " at iteration " << it + 1
              << " (lambda " << lambda << ", rho " << rho << ")";
            throw Error(s.str());
        }
        st.objective.push_back(e);
        st.data_term = data;
        st.tv_term = tv;
        const double change =
            (u - u_prev).norm().item<double>() / std::max(u.norm().item<double>(), 1e-12);
        st.rel_change.push_back(change);
        st.iterations = it + 1;
        if (change < options.tol) {
            st.converged = true;
            break;
        }
    }
    require_finite(u, "the deconvolved frame");
    if (options.clamp_output) u.clamp_min_(0.0);
    return finish(u);
}

Image deconvolve_frame(const Image& blurred, const Image& radius, const TvDeconvOptions& options,
                       TvDeconvStats* stats) {
    if (blurred.channels != 3)
        throw Error("deconvolve_frame: the frame must have 3 channels (linear RGB), got " +
                    std::to_string(blurred.channels));
    if (radius.channels != 1 || radius.width != blurred.width || radius.height != blurred.height) {
        std::ostringstream s;
        s << "deconvolve_frame: radius map must be " << blurred.width << "x" << blurred.height
          << "x1, got " << radius.width << "x" << radius.height << "x" << radius.channels;
        throw Error(s.str());
    }
    const int w = blurred.width, h = blurred.height;
    // HWC → CHW (copies: Image owns its pixels).
    auto g = torch::from_blob(const_cast<float*>(blurred.data()), {h, w, 3}, torch::kFloat32)
                 .permute({2, 0, 1})
                 .contiguous();
    auto r = torch::from_blob(const_cast<float*>(radius.data()), {h, w}, torch::kFloat32).clone();
    auto u = deconvolve_tv(g, r, options, stats).permute({1, 2, 0}).contiguous();
    Image out(w, h, 3);
    std::memcpy(out.data(), u.data_ptr<float>(), out.size() * sizeof(float));
    return out;
}

}  // namespace refocus
