// refocus bench kernel: how well each blur kernel of the lens blur layer explains a synth clip.
// The clip's ground truth gives the all-in-focus frame S_t and the true radius r_t; the input is
// the aperture renderer's I_t. For each kernel, PSNR(L(S_t, s·r_t), I_t) measures the model
// error that any fit with that kernel carries, away from the subject's silhouette (where a
// single-layer blur is wrong whatever the kernel: docs/method.md, Layered reblur).
#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdio>
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

struct KernelCase {
    std::string name;
    LensBlurParams params;
};

std::vector<KernelCase> kernel_cases() {
    std::vector<KernelCase> v;
    for (double beta : {2.0, 4.0, 8.0, 16.0}) {
        LensBlurParams p;
        p.beta = beta;
        char buf[32];
        std::snprintf(buf, sizeof buf, "disk b=%g", beta);
        v.push_back({buf, p});
    }
    LensBlurParams pb;
    pb.kernel = BlurKernel::Pillbox;
    v.push_back({"pillbox", pb});
    LensBlurParams g;
    g.kernel = BlurKernel::Gaussian;
    g.kappa = 0.5;
    v.push_back({"gauss k=0.5", g});
    return v;
}

// sRGB 8-bit PSNR over the pixels where `mask` [H,W] is 1.
double masked_psnr(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask) {
    auto d = (srgb8(a) - srgb8(b)).pow(2).sum(0);  // [H,W]
    const double n = mask.sum().item<double>() * a.size(0);
    if (n <= 0) return 0;
    const double mse = (d * mask).sum().item<double>() / n;
    return 10 * std::log10(255.0 * 255.0 / std::max(mse, 1e-12));
}

}  // namespace

int bench_kernel(int argc, char** argv) {
    Args a(argc, argv, 3);
    a.check_known({"clip", "frames", "scales"});
    if (!a.has("clip"))
        throw Error(
            "usage: refocus bench kernel --clip <synth-dir> [--frames 0,10,20] [--scales "
            "0.9,1,1.1]");
    const fs::path clip = a.get("clip");
    if (!fs::exists(clip / "clip.json"))
        throw Error(file_error(clip.string(), "not a refocus synth clip (no clip.json)"));
    const auto frames = parse_list(a.get("frames", "0,10,20"));
    const auto scales = parse_list(a.get("scales", "1"));
    namespace F = torch::nn::functional;
    const auto cases = kernel_cases();
    std::printf("clip %s: PSNR (dB, sRGB 8-bit) of L(sharp, s*coc) against the input\n",
                clip.string().c_str());
    std::printf("%-12s %6s %8s %10s %10s\n", "kernel", "s", "frame", "interior", "whole");
    for (const auto& kc : cases)
        for (double s : scales) {
            double sum_in = 0, sum_all = 0;
            for (double ft : frames) {
                const int t = static_cast<int>(ft);
                char buf[32];
                auto path = [&](const char* pass, const char* ext) {
                    std::snprintf(buf, sizeof buf, "%s_%04d.%s", pass, t, ext);
                    return (clip / buf).string();
                };
                auto sharp = image_to_tensor(read_image_file(path("sharp", "png")).image);
                auto input = image_to_tensor(read_image_file(path("input", "png")).image);
                auto coc = image_to_tensor(read_image_file(path("coc", "exr")).image)[0];
                auto alpha = image_to_tensor(read_image_file(path("alpha", "png"), false).image)[0];
                // Interior: no silhouette within the largest blur support (+3 px).
                const int R = static_cast<int>(std::ceil(coc.max().item<double>() * s)) + 3;
                auto edge = (alpha > 0.02) & (alpha < 0.98);
                auto near =
                    F::max_pool2d(edge.to(torch::kFloat32).unsqueeze(0).unsqueeze(0),
                                  F::MaxPool2dFuncOptions(2 * R + 1).stride(1).padding(R))[0][0];
                auto interior = 1.0 - near;
                // Also leave out the frame border band (light from outside the frame).
                interior.narrow(0, 0, R).zero_();
                interior.narrow(0, interior.size(0) - R, R).zero_();
                interior.narrow(1, 0, R).zero_();
                interior.narrow(1, interior.size(1) - R, R).zero_();
                auto out = lens_blur(sharp, coc * s, kc.params);
                const double pi = masked_psnr(out, input, interior);
                const double pa = masked_psnr(out, input, torch::ones_like(interior));
                sum_in += pi;
                sum_all += pa;
                std::printf("%-12s %6.2f %8d %10.2f %10.2f\n", kc.name.c_str(), s, t, pi, pa);
            }
            std::printf("%-12s %6.2f %8s %10.2f %10.2f\n", kc.name.c_str(), s, "mean",
                        sum_in / frames.size(), sum_all / frames.size());
            std::fflush(stdout);
        }
    return 0;
}

}  // namespace refocus
