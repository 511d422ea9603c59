// refocus bench <what>: benchmarks that print figures (they are not timed tests).
//   bench blur  the lens blur layer's fast path against a LibTorch tensor-ops version.
#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

#include "args.h"
#include "commands.h"
#include "ops/lens_blur.h"
#include "util/error.h"

namespace refocus {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Median wall time of `reps` runs of f (after `warmup` untimed runs).
double time_it(const std::function<void()>& f, int reps, int warmup) {
    for (int i = 0; i < warmup; ++i) f();
    std::vector<double> t;
    for (int i = 0; i < reps; ++i) {
        auto t0 = std::chrono::steady_clock::now();
        f();
        t.push_back(seconds_since(t0));
    }
    std::sort(t.begin(), t.end());
    return t[t.size() / 2];
}

BlurKernel parse_kernel(const std::string& s) {
    if (s == "disk") return BlurKernel::Disk;
    if (s == "pillbox") return BlurKernel::Pillbox;
    if (s == "gaussian") return BlurKernel::Gaussian;
    throw Error("--kernel must be disk, pillbox or gaussian (got '" + s + "')");
}

struct Map {
    std::string name;
    torch::Tensor radius;
};

std::vector<Map> blur_maps(int H, int W) {
    std::vector<Map> maps;
    for (double r : {0.0, 2.0, 8.0, 16.0}) {
        char name[32];
        std::snprintf(name, sizeof name, "all %g px", r);
        maps.push_back({name, torch::full({H, W}, r, torch::kFloat)});
    }
    // Realistic: left 40% sharp, right 40% at 8 px, a linear ramp over the middle 20%.
    torch::Tensor x = torch::arange(W, torch::kFloat) / float(W - 1);
    torch::Tensor row = ((x - 0.4f) / 0.2f).clamp(0, 1) * 8.0f;
    maps.push_back({"realistic", row.view({1, W}).expand({H, W}).contiguous()});
    return maps;
}

// refocus bench blur
int bench_blur(int argc, char** argv) {
    Args a(argc, argv, 3, {"no-tensor"});
    a.check_known(
        {"size", "kernel", "beta", "kappa", "reps", "tensor-reps", "no-tensor", "tensor-max-gb"});
    int W = 512, H = 288;
    std::string size = a.get("size", "512x288");
    if (std::sscanf(size.c_str(), "%dx%d", &W, &H) != 2 || W < 1 || H < 1)
        throw Error("--size needs WxH, e.g. 512x288 (got '" + size + "')");
    LensBlurParams p;
    p.kernel = parse_kernel(a.get("kernel", "disk"));
    p.beta = a.get_double("beta", p.beta);
    p.kappa = a.get_double("kappa", p.kappa);
    check_lens_blur_params(p);
    const int reps = std::max(1, a.get_int("reps", 5));
    const int treps = std::max(1, a.get_int("tensor-reps", 1));
    const bool with_tensor = !a.has("no-tensor");
    const double max_gb = a.get_double("tensor-max-gb", 4.0);

    torch::manual_seed(1);
    torch::Tensor img = torch::rand({3, H, W}, torch::kFloat);
    torch::Tensor wgt = torch::randn({3, H, W}, torch::kFloat);  // loss = Σ out·wgt

    std::printf(
        "refocus bench blur: %dx%dx3 float32, %s kernel, beta %g, %d threads, "
        "median of %d (tensor ops: %d)\n",
        W, H, a.get("kernel", "disk").c_str(), p.beta, at::get_num_threads(), reps, treps);
    std::printf(
        "taps: (source pixel, tap) pairs visited per pass; f+b counts both passes.\n"
        "tensor ops visit the whole (2R_max+1)^2 window; ratio = tensor time / fast "
        "time.\n\n");
    std::printf("%-11s %7s | %9s %7s | %9s %7s | %10s %10s | %7s %7s | %9s %9s\n", "map", "taps/px",
                "fwd ms", "Gtap/s", "f+b ms", "Gtap/s", "T fwd ms", "T f+b ms", "x fwd", "x f+b",
                "max|dOut|", "rel|dGr|");

    for (const Map& m : blur_maps(H, W)) {
        const int64_t taps = lens_blur_tap_count(m.radius, p);
        torch::Tensor out_fast, gi_fast, gr_fast;
        double t_fwd = time_it(
            [&] {
                torch::NoGradGuard ng;
                out_fast = lens_blur(img, m.radius, p);
            },
            reps, 1);
        double t_fb = time_it(
            [&] {
                torch::Tensor x = img.detach().requires_grad_(true);
                torch::Tensor r = m.radius.detach().requires_grad_(true);
                (lens_blur(x, r, p) * wgt).sum().backward();
                gi_fast = x.grad();
                gr_fast = r.grad();
            },
            reps, 1);

        std::string t_fwd_s = "-", t_fb_s = "-", x_fwd_s = "-", x_fb_s = "-", d_out = "-",
                    d_gr = "-";
        if (with_tensor) {
            const double rmax = m.radius.max().item<double>();
            const int R = static_cast<int>(std::floor(lens_blur_support(rmax, p)));
            const double k1 = 2.0 * R + 1;
            // About ten [K1²,H,W] float tensors live in the autograd graph at once.
            const double est_gb = 10.0 * k1 * k1 * H * W * 4 / 1e9;
            char buf[64];
            torch::Tensor out_t;
            double tt_fwd = time_it(
                [&] {
                    torch::NoGradGuard ng;
                    out_t = lens_blur_tensor_ops(img, m.radius, p);
                },
                treps, 0);
            std::snprintf(buf, sizeof buf, "%.1f", tt_fwd * 1e3);
            t_fwd_s = buf;
            std::snprintf(buf, sizeof buf, "%.1f", tt_fwd / t_fwd);
            x_fwd_s = buf;
            std::snprintf(buf, sizeof buf, "%.1e", (out_t - out_fast).abs().max().item<double>());
            d_out = buf;
            if (est_gb <= max_gb) {
                torch::Tensor gr_t;
                double tt_fb = time_it(
                    [&] {
                        torch::Tensor x = img.detach().requires_grad_(true);
                        torch::Tensor r = m.radius.detach().requires_grad_(true);
                        (lens_blur_tensor_ops(x, r, p) * wgt).sum().backward();
                        gr_t = r.grad();
                    },
                    treps, 0);
                std::snprintf(buf, sizeof buf, "%.1f", tt_fb * 1e3);
                t_fb_s = buf;
                std::snprintf(buf, sizeof buf, "%.1f", tt_fb / t_fb);
                x_fb_s = buf;
                double scale = std::max(gr_fast.abs().max().item<double>(), 1e-30);
                std::snprintf(buf, sizeof buf, "%.1e",
                              (gr_t - gr_fast).abs().max().item<double>() / scale);
                d_gr =
                    gr_fast.abs().max().item<double>() == 0 && gr_t.abs().max().item<double>() == 0
                        ? "0"
                        : buf;
            } else {
                std::snprintf(buf, sizeof buf, "skip%.0fGB", est_gb);
                t_fb_s = buf;
            }
        }
        std::printf("%-11s %7.1f | %9.2f %7.3f | %9.2f %7.3f | %10s %10s | %7s %7s | %9s %9s\n",
                    m.name.c_str(), double(taps) / (double(H) * W), t_fwd * 1e3, taps / t_fwd / 1e9,
                    t_fb * 1e3, 2.0 * taps / t_fb / 1e9, t_fwd_s.c_str(), t_fb_s.c_str(),
                    x_fwd_s.c_str(), x_fb_s.c_str(), d_out.c_str(), d_gr.c_str());
        std::fflush(stdout);
    }
    std::printf(
        "\nmax|dOut|: fast vs tensor-ops output; rel|dGr|: radius gradients, relative "
        "to max|grad|.\nskipNGB: tensor-ops f+b would need about N GB (raise "
        "--tensor-max-gb).\n");
    return 0;
}

struct Bench {
    const char* name;
    int (*run)(int, char**);
    const char* help;
};

// Add a benchmark here: `refocus bench <name> ...` calls run(argc, argv) with argv[2] == name.
const Bench kBenches[] = {
    {"blur", bench_blur,
     "blur [--size 512x288] [--kernel disk|pillbox|gaussian] [--beta B] [--reps N]\n"
     "             [--tensor-reps N] [--no-tensor] [--tensor-max-gb G]\n"
     "             lens blur layer: fast path vs LibTorch tensor ops"},
    {"fit", bench_fit,
     "fit --clip <synth-dir> [--preset P] [--minutes M] [--iters N] [--oracle-coc | --coc "
     "<pattern>]\n"
     "             [--oracle-mask | --mask <pattern>] [--at 0.5,1,2,5,10] [--csv out.csv] [--batch "
     "N]\n"
     "             [--seed S] [--work <dir>] [--set name=value]...\n"
     "             run time against error: sharp PSNR/SSIM/tPSNR vs ground truth, reblur PSNR\n"
     "       fit --clip <synth-dir> --score <project>\n"
     "             no fit: a fitted project's sharp output at its settings, scored the same way"},
    {"corpus", bench_corpus,
     "corpus <dir> [--split dev|val|all] [--preset P] [--minutes M | --iters N] [--oracle-coc]\n"
     "             [--csv FILE] [--seed S] [--batch N] [--set name=value]...\n"
     "             every clip of a corpus split fitted as bench fit does: one table of input\n"
     "             and output PSNR/SSIM/tPSNR, worst frame, PSNR inside/outside the mask\n"
     "             (CSV default: <dir>/bench_<split>_<preset>.csv)\n"
     "       corpus <dir> --views [--split S] [--csv FILE]\n"
     "             no fit: each rendered clip's sharpest-view bound (every pixel from the frame\n"
     "             that saw it sharpest, by the true depth, cameras and radius)"},
    {"motion", bench_motion,
     "motion --clip <synth-dir> [--pairs] [--dump <dir>]\n"
     "             camera motion (prepare's homographies) against the clip's true wall motion"},
    {"kernel", bench_kernel,
     "kernel --clip <synth-dir> [--frames 0,10,20] [--scales 1]\n"
     "             how well each blur kernel reblurs the clip's ground truth into its input"},
    {"bound", bench_bound,
     "bound --clip <synth-dir> [--sharp <dir>] [--lambdas 1e-6,1e-5] [--iters 300]\n"
     "             the wall's best 1x atlas and best linear (Wiener) deconvolution, given the "
     "truth"},
    {"scale", bench_scale,
     "scale [--scene rack] [--sizes 320x180,640x360,1280x720,1920x1080] [--frames 30]\n"
     "             [--max-minutes 10] [--crop-px 320] [--work <dir>] [--set name=value]...\n"
     "             cost against frame size: ingest, preparation, a step on whole frames and on "
     "crops,\n"
     "             time to the input's sharp PSNR + 3 dB (true radius), peak memory"},
};

}  // namespace

int cmd_bench(int argc, char** argv) {
    std::string which = argc > 2 ? argv[2] : "";
    for (const auto& b : kBenches)
        if (which == b.name) return b.run(argc, argv);
    // The list goes to stderr first: main prints only an error's first line.
    std::fprintf(stderr, "available:\n");
    for (const auto& b : kBenches) std::fprintf(stderr, "  refocus bench %s\n", b.help);
    throw Error(which.empty() ? "which benchmark? (listed above)"
                              : "unknown benchmark '" + which + "' (listed above)");
}

}  // namespace refocus
