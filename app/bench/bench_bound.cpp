// refocus bench bound: how sharp can any linear reconstruction get a synth clip's background?
//
// A fit's error on a wall that no frame saw in focus has two parts: what the model (a 1x atlas
// moved onto each frame) cannot hold, and what the blurred frames do not say. This bench
// measures both on the clip's own ground truth, away from the subject and the frame's rim,
// with everything a fit has to find given for free (the camera's true shake, the true radius,
// the lens blur layer's kernel and the truth's own spectrum):
//   - ceiling: the truth itself, moved onto one phase and averaged (A0 = mean_t S_t^-1 G_t over
//     the frames that see the wall there), then moved back onto each frame: the best any 1x
//     atlas does, whatever the data;
//   - bound: the wall's blurred atlas B = mean_t S_t^-1 I_t (the input frames moved onto one
//     phase; a camera that only shakes and a focus that holds still give one blur per point,
//     so B = L(A, r)), deconvolved by the Wiener estimate with the truth's power spectrum P(f)
//     (seed 001 eq. 1.5 with a Gaussian prior of that spectrum):
//         min_A  sum_x w(x) (L(A, r)(x) - B(x))^2  +  lambda sum_f |A^(f)|^2 / P(f),
//     solved by conjugate gradients with the lens blur layer and its adjoint. With the truth's
//     spectrum this is the best linear estimate (the MMSE one for a Gaussian signal); a fit's
//     priors (TV) are not linear and may pass it, but not by much where the blur left the
//     detail under the 8-bit frames' rounding.
// `--sharp <dir>` scores a fit's exported sharp frames (sharp_%04d.png) on the same pixels.
#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "args.h"
#include "bench_util.h"
#include "commands.h"
#include "io/tensor_image.h"
#include "io/image_file.h"
#include "ops/lens_blur.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

namespace F = torch::nn::functional;
using torch::indexing::Slice;

// out(x) = in(x - s) for s = (sx, sy) px, by the Fourier shift theorem on a periodic domain:
// unitary, so its adjoint is the shift by -s. [C,H,W] double.
torch::Tensor fourier_shift(const torch::Tensor& x, double sx, double sy) {
    const int64_t h = x.size(-2), w = x.size(-1);
    auto opts = torch::TensorOptions().dtype(torch::kFloat64);
    auto fy = torch::fft::fftfreq(h, 1.0, opts).view({h, 1});
    auto fx = torch::fft::fftfreq(w, 1.0, opts).view({1, w});
    auto phase = torch::polar(torch::ones({h, w}, opts), -2 * M_PI * (fx * sx + fy * sy));
    return torch::real(torch::fft::ifft2(torch::fft::fft2(x) * phase));
}

// 1 where no pixel of `alpha` [H,W] > 0 lies within `r` px (a square window).
torch::Tensor away_from(const torch::Tensor& alpha, int r) {
    auto a = (alpha > 0).to(torch::kFloat64).unsqueeze(0).unsqueeze(0);
    return 1.0 - F::max_pool2d(a, F::MaxPool2dFuncOptions(2 * r + 1).stride(1).padding(r))[0][0];
}

// Pads [C,H,W] by p on every side, repeating the edge.
torch::Tensor pad_edge(const torch::Tensor& x, int64_t p) {
    return F::pad(x.unsqueeze(0), F::PadFuncOptions({p, p, p, p}).mode(torch::kReplicate))[0];
}

// Masked mean of frames moved onto one phase: sum_t S_t^-1 (m_t v_t) / sum_t S_t^-1 m_t,
// on a domain padded by p (periodic shifts wrap only within the pad). Also returns the
// coverage sum_t S_t^-1 m_t / T.
std::pair<torch::Tensor, torch::Tensor> unshifted_mean(const std::vector<torch::Tensor>& v,
                                                       const std::vector<torch::Tensor>& m,
                                                       const std::vector<std::array<double, 2>>& s,
                                                       int64_t p) {
    torch::Tensor num, den;
    for (size_t t = 0; t < v.size(); ++t) {
        auto mt = pad_edge(m[t].unsqueeze(0), p);
        auto nt = fourier_shift(pad_edge(v[t], p) * mt, -s[t][0], -s[t][1]);
        auto dt = fourier_shift(mt, -s[t][0], -s[t][1]);
        num = num.defined() ? num + nt : nt;
        den = den.defined() ? den + dt : dt;
    }
    return {num / den.clamp_min(1e-3), den / static_cast<double>(v.size())};
}

struct Score {
    double se = 0, n = 0;
    void add(const torch::Tensor& pred, const torch::Tensor& gt, const torch::Tensor& mask) {
        auto d = (srgb8(pred) - srgb8(gt)).pow(2).sum(0);
        se += (d * mask).sum().item<double>();
        n += mask.sum().item<double>() * pred.size(0);
    }
    double psnr() const {
        return n > 0 ? 10 * std::log10(255.0 * 255.0 * n / std::max(se, 1e-9)) : 0;
    }
};

// A synth clip whose camera only shakes: its passes and the shake per frame.
struct BoundClip {
    int T = 0;
    int64_t H = 0, W = 0;
    std::string json_path;
    std::vector<std::array<double, 2>> shake;
    std::vector<torch::Tensor> input, truth, coc, alpha, sharp;  // sharp: a fit's export (optional)
};

BoundClip load_bound_clip(const fs::path& clip, const std::string& sharp_dir) {
    BoundClip bc;
    bc.json_path = (clip / "clip.json").string();
    if (!fs::exists(bc.json_path))
        throw Error(file_error(clip.string(), "not a refocus synth clip (no clip.json)"));
    nlohmann::json j;
    try {
        std::ifstream f(bc.json_path);
        f >> j;
    } catch (const std::exception& e) {
        throw Error(file_error(bc.json_path, std::string("unreadable: ") + e.what()));
    }
    bc.T = j.value("frames", 0);
    const int T = bc.T;
    const auto& cam = j.at("camera");
    if (T < 1 || cam.at("pan").size() != static_cast<size_t>(T) ||
        cam.at("shake_px").size() != static_cast<size_t>(T))
        throw Error(file_error(bc.json_path, "frames, camera.pan and camera.shake_px disagree"));
    bc.shake.resize(T);
    for (int t = 0; t < T; ++t) {
        if (std::abs(cam["pan"][t].get<double>()) > 1e-9)
            throw Error(
                file_error(bc.json_path, "the camera pans (frame " + std::to_string(t) +
                                             "): this bound needs a camera that only shakes"));
        bc.shake[t] = {cam["shake_px"][t][0].get<double>(), cam["shake_px"][t][1].get<double>()};
    }
    auto path = [&](const fs::path& dir, const char* pass, int t, const char* ext) {
        char buf[40];
        std::snprintf(buf, sizeof buf, "%s_%04d.%s", pass, t, ext);
        return (dir / buf).string();
    };
    auto load = [](const std::string& p, bool srgb) {
        return image_to_tensor(read_image_file(p, srgb).image).to(torch::kFloat64);
    };
    bc.input.resize(T), bc.truth.resize(T), bc.coc.resize(T), bc.alpha.resize(T);
    auto &input = bc.input, &truth = bc.truth, &coc = bc.coc, &alpha = bc.alpha;
    for (int t = 0; t < T; ++t) {
        input[t] = load(path(clip, "input", t, "png"), true);
        truth[t] = load(path(clip, "sharp", t, "png"), true);
        coc[t] = load(path(clip, "coc", t, "exr"), false)[0];
        alpha[t] = load(path(clip, "alpha", t, "png"), false)[0];
        if (input[t].sizes() != truth[t].sizes() || coc[t].sizes() != input[t][0].sizes())
            throw Error(file_error(path(clip, "input", t, "png"),
                                   "its size differs from the clip's other passes"));
    }
    if (!sharp_dir.empty()) {
        for (int t = 0; t < T; ++t) {
            bc.sharp.push_back(load(path(sharp_dir, "sharp", t, "png"), true));
            if (bc.sharp.back().sizes() != truth[t].sizes())
                throw Error(
                    file_error(path(sharp_dir, "sharp", t, "png"), "not the clip's frame size"));
        }
    }
    bc.H = input[0].size(1);
    bc.W = input[0].size(2);
    return bc;
}

// The wall's blur moved onto one phase: R (the operator's margin, px), the circle of confusion
// per point [1,H+2R,W+2R] and the kernel's radius for it. Throws where the frames disagree on
// a point's blur by more than 0.25 px (focus moves): the bound needs one blur per point.
struct WallBlur {
    int64_t R;
    torch::Tensor rad, kr;
};

WallBlur wall_blur(const BoundClip& bc, const std::vector<torch::Tensor>& wall_gt,
                   const LensBlurParams& lp) {
    const int T = bc.T;
    const int64_t H = bc.H, W = bc.W;
    const auto& coc = bc.coc;
    const auto& shake = bc.shake;
    const std::string& json_path = bc.json_path;
    // The kernel's radius for each circle of confusion, by a table (the conversion bisects).
    double cmax = 0;
    for (const auto& c : coc) cmax = std::max(cmax, c.max().item<double>());
    const int64_t R = static_cast<int64_t>(std::ceil(lens_blur_support(cmax + 1, lp))) + 2;
    std::vector<double> table;
    const double step = 0.01;
    for (double c = 0; c <= cmax + 2 * step; c += step)
        table.push_back(kernel_radius_for_coc(c, lp));
    auto to_kernel = [&](torch::Tensor c) {
        auto idx = (c / step).clamp(0, static_cast<double>(table.size() - 2));
        auto i0 = idx.floor();
        auto f = idx - i0;
        auto tab = torch::tensor(table, torch::kFloat64);
        auto i = i0.to(torch::kLong);
        return tab.index({i}) * (1 - f) + tab.index({i + 1}) * f;
    };

    // One blur per wall point: the radius maps moved onto one phase must agree.
    auto [rad, rcov] = unshifted_mean(
        [&] {
            std::vector<torch::Tensor> v;
            for (auto& c : coc) v.push_back(c.unsqueeze(0));
            return v;
        }(),
        wall_gt, shake, R);
    double spread = 0;
    for (int t = 0; t < T; ++t) {
        auto mt = pad_edge(wall_gt[t].unsqueeze(0), R);
        auto ms = fourier_shift(mt, -shake[t][0], -shake[t][1]);
        auto ct = fourier_shift(pad_edge(coc[t].unsqueeze(0), R) * mt, -shake[t][0], -shake[t][1]) /
                  ms.clamp_min(1e-3);
        auto mm = ms > 0.99;
        auto inner = torch::zeros_like(mm);
        inner.index_put_({Slice(), Slice(R + 2, R + H - 2), Slice(R + 2, R + W - 2)}, true);
        mm = mm & inner;
        if (mm.any().item<bool>())
            spread = std::max(spread, (ct - rad).abs().masked_select(mm).max().item<double>());
    }
    if (spread > 0.25)
        throw Error(
            file_error(json_path, "the wall's blur changes between frames (by up to " +
                                      std::to_string(spread) +
                                      " px; focus moves): this bound needs one blur per point"));
    // Where no frame sees the wall, borrow the row's radius (the wall's blur follows its rows
    // in these scenes) so the operator stays defined; those pixels carry no data.
    auto seen = rcov > 1e-3;
    auto row_mean = (rad * seen).sum(-1, true) / seen.sum(-1, true).clamp_min(1);
    rad = torch::where(seen, rad, row_mean.expand_as(rad));
    auto kr = to_kernel(rad[0]);
    return {R, rad, kr};
}

}  // namespace

int bench_bound(int argc, char** argv) {
    Args a(argc, argv, 3);
    a.check_known({"clip", "sharp", "lambdas", "iters"});
    if (!a.has("clip"))
        throw Error(
            "usage: refocus bench bound --clip <synth-dir> [--sharp <dir>] [--lambdas 1e-6,1e-5] "
            "[--iters 300]");
    const std::vector<double> lambdas = parse_list(a.get("lambdas", "3e-7,1e-6,3e-6,1e-5,3e-5"));
    const int iters = std::stoi(a.get("iters", "300"));

    const fs::path clip = a.get("clip");
    BoundClip bc = load_bound_clip(clip, a.get("sharp"));
    const int T = bc.T;
    const auto& shake = bc.shake;
    const auto &input = bc.input, &truth = bc.truth, &alpha = bc.alpha, &sharp = bc.sharp;
    const int64_t H = bc.H, W = bc.W;
    // The wall as each frame sees it: no subject within 12 px (the subject's own blur and the
    // wall's occlusion behind it) for the inputs, within 3 px for the truth (its soft edge).
    std::vector<torch::Tensor> wall_in(T), wall_gt(T);
    for (int t = 0; t < T; ++t) {
        wall_in[t] = away_from(alpha[t], 12);
        wall_gt[t] = away_from(alpha[t], 3);
    }
    LensBlurParams lp;
    lp.kernel = BlurKernel::Pillbox;
    const WallBlur wb = wall_blur(bc, wall_gt, lp);
    const int64_t R = wb.R;
    const torch::Tensor rad = wb.rad, kr = wb.kr;

    auto [B, bcov] = unshifted_mean(input, wall_in, shake, R);
    auto [A0, gcov] = unshifted_mean(truth, wall_gt, shake, R);
    auto data_w = torch::zeros({1, H + 2 * R, W + 2 * R}, torch::kFloat64);
    data_w.index_put_(
        {Slice(), Slice(R, R + H), Slice(R, R + W)},
        (bcov.index({Slice(), Slice(R, R + H), Slice(R, R + W)}) > 0.2).to(torch::kFloat64));
    // The truth's power spectrum (channels averaged, 3x3 bins smoothed); the mean is free.
    const auto A0c = A0 - A0.mean({1, 2}, true);
    auto P = torch::fft::fft2(A0c).abs().pow(2).mean(0);
    P = F::avg_pool2d(
        F::pad(P.unsqueeze(0).unsqueeze(0), F::PadFuncOptions({1, 1, 1, 1}).mode(torch::kCircular)),
        F::AvgPool2dFuncOptions(3).stride(1))[0][0];
    P = P / static_cast<double>(P.numel());
    auto inv_p = (1.0 / P.clamp_min(1e-12));
    inv_p.index_put_({0, 0}, 0.0);

    auto blur = [&](const torch::Tensor& x) { return lens_blur(x, kr, lp); };
    auto blur_t = [&](const torch::Tensor& x) { return lens_blur_adjoint(x, kr, lp); };
    auto solve = [&](double lambda) {
        auto prior = [&](const torch::Tensor& v) {
            return torch::real(torch::fft::ifft2(torch::fft::fft2(v) * (lambda * inv_p)));
        };
        auto op = [&](const torch::Tensor& v) { return blur_t(data_w * blur(v)) + prior(v); };
        auto x = B.clone();
        auto r = blur_t(data_w * B) - op(x);
        auto p = r.clone();
        double rs = (r * r).sum().item<double>();
        for (int i = 0; i < iters && rs > 1e-30; ++i) {
            auto Ap = op(p);
            const double al = rs / (p * Ap).sum().item<double>();
            x = x + al * p;
            r = r - al * Ap;
            const double rn = (r * r).sum().item<double>();
            p = r + (rn / rs) * p;
            rs = rn;
        }
        return x;
    };

    // Scored on the wall's interior: no subject within 25 px, no frame rim within 14 px.
    std::vector<torch::Tensor> eval_mask(T);
    double px = 0;
    for (int t = 0; t < T; ++t) {
        auto m = away_from(alpha[t], 25);
        const int64_t b = std::min<int64_t>(14, std::min(H, W) / 4);
        m.narrow(0, 0, b).zero_();
        m.narrow(0, H - b, b).zero_();
        m.narrow(1, 0, b).zero_();
        m.narrow(1, W - b, b).zero_();
        eval_mask[t] = m;
        px += m.sum().item<double>();
    }
    auto crop = [&](const torch::Tensor& x) {
        return x.index({Slice(), Slice(R, R + H), Slice(R, R + W)});
    };
    auto score_atlas = [&](const torch::Tensor& atlas) {
        Score s;
        for (int t = 0; t < T; ++t)
            s.add(crop(fourier_shift(atlas, shake[t][0], shake[t][1])), truth[t], eval_mask[t]);
        return s.psnr();
    };
    auto score_frames = [&](const std::vector<torch::Tensor>& frames) {
        Score s;
        for (int t = 0; t < T; ++t) s.add(frames[t], truth[t], eval_mask[t]);
        return s.psnr();
    };
    std::printf(
        "clip %s (%lldx%lld, %d frames): the wall away from the subject and the rim, "
        "%.0f px a frame; blur %.2f-%.2f px\n",
        clip.string().c_str(), static_cast<long long>(W), static_cast<long long>(H), T, px / T,
        crop(rad).min().item<double>(), crop(rad).max().item<double>());
    std::printf("%-44s %10s\n", "", "PSNR (dB)");
    std::printf("%-44s %10.2f\n", "input", score_frames(input));
    std::printf("%-44s %10.2f\n", "ceiling: the truth on one phase (1x atlas)", score_atlas(A0));
    std::fflush(stdout);
    double best = -1, best_lambda = 0;
    for (double lambda : lambdas) {
        const double p = score_atlas(solve(lambda));
        char name[64];
        std::snprintf(name, sizeof name, "bound: Wiener at lambda %g", lambda);
        std::printf("%-44s %10.2f\n", name, p);
        std::fflush(stdout);
        if (p > best) best = p, best_lambda = lambda;
    }
    if (!sharp.empty()) std::printf("%-44s %10.2f\n", "fit (--sharp)", score_frames(sharp));
    std::printf("best bound %.2f dB at lambda %g\n", best, best_lambda);
    return 0;
}

}  // namespace refocus
