// Two slow versions of the lens blur layer that the fast path (lens_blur.cpp) is checked
// against: a plain-loop reference in long double, and a LibTorch tensor-ops version for the
// benchmark. Both implement the conventions in lens_blur.h from the equations directly.
#include <torch/nn/functional/fold.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "ops/lens_blur.h"
#include "util/error.h"

namespace refocus {

namespace {

using LD = long double;

LD disk_tail(const LensBlurParams& p) {
    return std::max<LD>(kDiskTail / p.beta, kDiskTailMin);
}

// Paper eq. 2 exactly as printed, k = e^{βd} / (e^{βd} − d). In long double e^{βd} only
// overflows for βd > 11356, far beyond what the tests use.
LD paper_disk(LD d, LD beta) {
    LD e = std::exp(beta * d);
    return e / (e - d);
}

// Seed 001 eq. 1.20, constant factor included.
LD gaussian(LD rho, LD sigma) {
    return std::exp(-rho * rho / (2 * sigma * sigma)) / (2 * M_PI * sigma * sigma);
}

// k̃(ρ; r), zero outside the support (header conventions).
LD ref_kernel(const LensBlurParams& p, LD r, LD rho) {
    switch (p.kernel) {
        case BlurKernel::Disk: {
            LD te = disk_tail(p);
            LD d = r - rho;
            if (d <= -te) return 0;
            return paper_disk(d, p.beta) - paper_disk(-te, p.beta);
        }
        case BlurKernel::Pillbox:
            return std::clamp<LD>(r + 0.5L - rho, 0, 1);
        case BlurKernel::Gaussian: {
            LD sigma = p.kappa * r;
            if (rho >= kGaussianTail * sigma) return 0;
            return gaussian(rho, sigma) - gaussian(kGaussianTail * sigma, sigma);
        }
    }
    return 0;
}

LD smoothstep_blend(LD r, LD rmin) {
    LD t = std::clamp<LD>((r - rmin) / kBlendWidth, 0, 1);
    return t * t * (3 - 2 * t);
}

}  // namespace

torch::Tensor lens_blur_reference(const torch::Tensor& image, const torch::Tensor& radius,
                                  const LensBlurParams& params) {
    check_lens_blur_params(params);
    torch::NoGradGuard ng;
    torch::Tensor img = image.to(torch::kDouble).contiguous();
    torch::Tensor rad = radius.to(torch::kDouble).contiguous();
    const int C = img.size(0), H = img.size(1), W = img.size(2);
    if (rad.size(0) != H || rad.size(1) != W) throw Error("lens_blur_reference: shape mismatch");
    auto I = img.accessor<double, 3>();
    auto Rd = rad.accessor<double, 2>();
    std::vector<LD> out(static_cast<size_t>(C) * H * W, 0);
    auto at = [&](int c, int y, int x) -> LD& {
        return out[(static_cast<size_t>(c) * H + y) * W + x];
    };
    struct Tap {
        int y, x;
        LD k;
    };
    std::vector<Tap> taps;
    for (int py = 0; py < H; ++py) {
        for (int px = 0; px < W; ++px) {
            const LD r = Rd[py][px];
            const LD s = smoothstep_blend(r, params.min_radius);
            if (s == 0) {  // r ≤ min_radius: the identity
                for (int c = 0; c < C; ++c) at(c, py, px) += I[c][py][px];
                continue;
            }
            const int B = static_cast<int>(std::ceil(lens_blur_support(r, params))) + 1;
            taps.clear();
            LD S = 0;
            for (int dy = -B; dy <= B; ++dy) {
                for (int dx = -B; dx <= B; ++dx) {
                    int qy = py + dy, qx = px + dx;
                    if (qy < 0 || qy >= H || qx < 0 || qx >= W) continue;  // border rule: dropped
                    LD k = ref_kernel(params, r, std::sqrt(LD(dx) * dx + LD(dy) * dy));
                    if (k <= 0) continue;
                    taps.push_back({qy, qx, k});
                    S += k;
                }
            }
            for (int c = 0; c < C; ++c) {
                const LD v = I[c][py][px];
                for (const Tap& t : taps) at(c, t.y, t.x) += v * s * t.k / S;
                at(c, py, px) += (1 - s) * v;
            }
        }
    }
    torch::Tensor res = torch::empty({C, H, W}, torch::kDouble);
    double* rp = res.data_ptr<double>();
    for (size_t i = 0; i < out.size(); ++i) rp[i] = static_cast<double>(out[i]);
    return res;
}

torch::Tensor lens_blur_tensor_ops(const torch::Tensor& image, const torch::Tensor& radius,
                                   const LensBlurParams& params) {
    namespace F = torch::nn::functional;
    check_lens_blur_params(params);
    const int64_t C = image.size(0), H = image.size(1), W = image.size(2);
    const auto opts = image.options();
    torch::Tensor r = radius.to(image.scalar_type());
    const double rmax = r.max().item<double>();
    const int R = std::min<int>(static_cast<int>(std::floor(lens_blur_support(rmax, params))),
                                static_cast<int>(std::max(H, W)));
    torch::Tensor t = ((r - params.min_radius) / kBlendWidth).clamp(0, 1);
    torch::Tensor s = t * t * (3 - 2 * t);  // [H,W]
    if (R <= 0) return image * (1 - s);

    const int64_t K1 = 2 * R + 1;
    torch::Tensor rr = r.unsqueeze(0);  // [1,H,W]
    torch::Tensor dx = torch::arange(-R, R + 1, opts).view({K1, 1, 1});
    torch::Tensor ys = torch::arange(H, torch::kLong).view({1, H, 1});
    torch::Tensor xs = torch::arange(W, torch::kLong).view({1, 1, W});
    torch::Tensor dxl = torch::arange(-R, R + 1, torch::kLong).view({K1, 1, 1});
    const double te = std::max(kDiskTail / params.beta, kDiskTailMin);
    const double disk_edge = std::exp(-params.beta * te) / (std::exp(-params.beta * te) + te);
    const auto k_dtype = image.scalar_type();
    const double gauss_edge = std::exp(-0.5 * kGaussianTail * kGaussianTail);

    // k̃ for one kernel row dy, masked to in-image taps: [K1,H,W].
    auto kernel_row = [&](int dy) {
        torch::Tensor rho = torch::sqrt(dx * dx + double(dy) * dy);
        torch::Tensor k;
        switch (params.kernel) {
            case BlurKernel::Disk: {
                // Both branches finite everywhere: 1/(1 − d·e^{−βd}) on d ≥ 0 and
                // e^{βd}/(e^{βd} − d) on −t_e ≤ d < 0; the support mask is strict (ρ < R_s),
                // as in the fast path, so a tap exactly at the edge has zero derivative.
                torch::Tensor d = rr - rho;
                torch::Tensor dp = d.clamp_min(0);
                torch::Tensor dn = d.clamp(-te, 0);
                torch::Tensor en = torch::exp(params.beta * dn);
                torch::Tensor kp = 1.0 / (1.0 - dp * torch::exp(-params.beta * dp));
                torch::Tensor kn = en / (en - dn);
                k = (torch::where(d >= 0, kp, kn) - disk_edge) * (d > -te).to(k_dtype);
                break;
            }
            case BlurKernel::Pillbox:
                k = (rr + 0.5 - rho).clamp(0, 1);
                break;
            case BlurKernel::Gaussian: {
                torch::Tensor sigma = params.kappa * rr.clamp_min(1e-6);
                k = (torch::exp(-(rho * rho) / (2 * sigma * sigma)) - gauss_edge).clamp_min(0);
                break;
            }
        }
        torch::Tensor inside =
            ((ys + dy) >= 0) & ((ys + dy) < H) & ((xs + dxl) >= 0) & ((xs + dxl) < W);
        return k * inside.to(image.scalar_type());
    };

    std::vector<torch::Tensor> rows;
    rows.reserve(K1);
    torch::Tensor S = torch::zeros({H, W}, opts);
    for (int dy = -R; dy <= R; ++dy) {
        rows.push_back(kernel_row(dy));
        S = S + rows.back().sum(0);
    }
    torch::Tensor a = s / S;
    torch::Tensor out = image * (1 - s);
    for (int dy = -R; dy <= R; ++dy) {
        if (std::abs(dy) >= H) continue;
        torch::Tensor w = rows[dy + R] * a;                     // [K1,H,W]
        torch::Tensor x = image.unsqueeze(1) * w.unsqueeze(0);  // [C,K1,H,W]
        // fold sums each source pixel's row of K1 taps into columns px−R..px+R.
        torch::Tensor row_out = F::fold(x.reshape({1, C * K1, H * W}),
                                        F::FoldFuncOptions({H, W}, {1, K1}).padding({0, R}))
                                    .squeeze(0);  // [C,H,W], row i = source row i
        torch::Tensor part = row_out.narrow(1, std::max(0, -dy), H - std::abs(dy));
        out = out + torch::constant_pad_nd(part, {0, 0, std::max(0, dy), std::max(0, -dy)});
    }
    return out;
}

}  // namespace refocus
