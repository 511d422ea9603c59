// refocus-preview-bench: the real-time preview's frame time at 512×288, GLSL on OSMesa
// (llvmpipe: this machine's software GL) beside the CPU twin (engine/render/preview.cpp), for
// max radius 8 and 16, circle and 6 blades: the exact GLSL path, the fast one (frames/s of
// both), the CPU twin, and the fast path's error against the exact one (PSNR). A frame =
// composite (paper eq. 1) + layered depth of field, with the frame's UV/alpha upload on the GL
// side. Then the fast path's time per pass (each pass waited for).
// Usage: refocus-preview-bench [--frames N] [--size WxH] [--threads T] [--no-cpu]
//                              [--dump PREFIX]  (PREFIX<r>_<shape>_{exact,fast,diff}.ppm)
#include <GL/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

#include "gl_preview.h"
#include "headless_gl.h"
#include "render/preview.h"

using namespace refocus;

namespace {

double now_ms() {
    using namespace std::chrono;
    return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

// PSNR (dB) of `b` against `a` as the viewer shows them: linear light clipped to [0, 1], peak 1.
double psnr(const Image& a, const Image& b) {
    double se = 0.0;
    for (size_t i = 0; i < a.size(); ++i) {
        const double d = std::min(std::max(a.pixels[i], 0.0f), 1.0f) -
                         std::min(std::max(b.pixels[i], 0.0f), 1.0f);
        se += d * d;
    }
    const double mse = se / a.size();
    return mse > 0.0 ? 10.0 * std::log10(1.0 / mse) : 999.0;
}

// Binary PPM, sRGB-ish (gamma 2.2, clipped), for looking at the fast path's error.
void write_ppm(const std::string& path, const Image& img, float scale = 1.0f) {
    FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) return;
    std::fprintf(f, "P6\n%d %d\n255\n", img.width, img.height);
    for (size_t i = 0; i < static_cast<size_t>(img.width) * img.height; ++i)
        for (int c = 0; c < 3; ++c) {
            const float v =
                std::min(std::max(img.pixels[i * img.channels + c] * scale, 0.0f), 1.0f);
            std::fputc(static_cast<int>(std::pow(v, 1.0f / 2.2f) * 255.0f + 0.5f), f);
        }
    std::fclose(f);
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

struct Scene {
    Image bg_atlas, fg_atlas, bg_uv, fg_uv, alpha;
    PreviewDepth depth;
};

// A textured background atlas seen through a slight zoom, a subject disc on the foreground
// atlas; background inverse depth a left-to-right ramp, the subject at one depth.
Scene make_scene(int w, int h) {
    Scene s;
    const int aw = w + w / 4, ah = h + h / 4;
    s.bg_atlas = Image(aw, ah, 3);
    s.fg_atlas = Image(aw, ah, 3);
    for (int y = 0; y < ah; ++y)
        for (int x = 0; x < aw; ++x) {
            const bool check = ((x / 12) + (y / 12)) % 2;
            s.bg_atlas.at(x, y, 0) = check ? 0.8f : 0.1f;
            s.bg_atlas.at(x, y, 1) = 0.3f + 0.4f * x / aw;
            s.bg_atlas.at(x, y, 2) = 0.5f + 0.4f * std::sin(y * 0.1f);
            if ((x * 7 + y * 13) % 211 == 0)  // highlights
                for (int c = 0; c < 3; ++c) s.bg_atlas.at(x, y, c) = 6.0f;
            s.fg_atlas.at(x, y, 0) = 0.9f;
            s.fg_atlas.at(x, y, 1) = 0.6f + 0.3f * ((x / 4 + y / 4) % 2);
            s.fg_atlas.at(x, y, 2) = 0.4f;
        }
    s.bg_uv = Image(w, h, 2);
    s.fg_uv = Image(w, h, 2);
    s.alpha = Image(w, h, 1);
    s.depth.background = Image(w, h, 1);
    s.depth.foreground_const = 0.6f;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const float u = (2.0f * x + 1.0f) / w - 1.0f, v = (2.0f * y + 1.0f) / h - 1.0f;
            s.bg_uv.at(x, y, 0) = 0.8f * u;
            s.bg_uv.at(x, y, 1) = 0.8f * v;
            s.fg_uv.at(x, y, 0) = 0.7f * u + 0.05f;
            s.fg_uv.at(x, y, 1) = 0.7f * v;
            const float r = std::hypot(x - 0.55f * w, y - 0.5f * h);
            s.alpha.at(x, y, 0) = std::min(std::max(0.3f * h - r, 0.0f), 1.0f);
            s.depth.background.at(x, y, 0) = static_cast<float>(x) / w;
        }
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    int frames = 5, w = 512, h = 288, threads = 2;
    bool cpu_twin = true;
    std::string dump;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--frames" && i + 1 < argc) {
            frames = std::max(1, std::atoi(argv[++i]));
        } else if (a == "--size" && i + 1 < argc) {
            if (std::sscanf(argv[++i], "%dx%d", &w, &h) != 2 || w < 1 || h < 1) {
                std::fprintf(stderr, "refocus-preview-bench: --size needs WxH\n");
                return 2;
            }
        } else if (a == "--dump" && i + 1 < argc) {
            dump = argv[++i];
        } else if (a == "--no-cpu") {
            cpu_twin = false;
        } else if (a == "--threads" && i + 1 < argc) {
            threads = std::max(1, std::atoi(argv[++i]));
        } else {
            std::fprintf(stderr,
                         "usage: refocus-preview-bench [--frames N] [--size WxH] "
                         "[--threads T] [--no-cpu] [--dump PREFIX]\n");
            return 2;
        }
    }
    try {
        HeadlessGl gl;
        GlPreview gp;
        const char* lp = std::getenv("LP_NUM_THREADS");
        std::printf(
            "GL: %s (LP_NUM_THREADS=%s)\nframe %dx%d, median of %d frames; CPU twin on "
            "%d thread(s)\n",
            HeadlessGl::renderer().c_str(), lp ? lp : "default", w, h, frames, threads);
        const Scene s = make_scene(w, h);
        gp.set_atlases(s.bg_atlas, s.fg_atlas);
        gp.set_depth(s.depth);
        std::printf("%-6s %-9s %10s %10s %9s %9s %11s %10s %10s %9s %11s %10s\n", "max_r",
                    "aperture", "exact ms", "fast ms", "exact fps", "fast fps", "exact cpu-ms",
                    "fast cpu-ms", "twin ms", "PSNR dB", "max |diff|", "twin-exact");
        std::vector<std::pair<std::string, double>> passes;
        for (double max_r : {8.0, 16.0})
            for (int blades : {0, 6}) {
                PreviewLens lens;
                lens.aperture = 2.0 * max_r;  // bg radius 0 … max_r (clamped), subject ~0.2·A
                lens.focus = 0.5;
                lens.max_radius = max_r;
                lens.blades = blades;
                lens.rotation_deg = 15.0;
                lens.highlight_threshold = 1.0;
                lens.highlight_gain = 0.5;
                // Process CPU time per frame (llvmpipe's threads included): what a frame costs
                // whatever else the machine runs; frames/s on an idle machine with C cores is
                // at most C·1000 / cpu_ms.
                double cpu_frame_ms = 0.0;
                auto time_gl = [&](PreviewQuality q, Image& out) {
                    std::vector<double> ms;
                    std::clock_t c0 = 0;
                    for (int f = 0; f <= frames; ++f) {  // frame 0: warm-up (JIT, tables)
                        const double t0 = now_ms();
                        gp.set_frame(s.bg_uv, s.fg_uv, s.alpha);
                        gp.render(lens, q);
                        glFinish();
                        const double t1 = now_ms();
                        if (f > 0) ms.push_back(t1 - t0);
                        if (f == 0) c0 = std::clock();
                    }
                    cpu_frame_ms = 1000.0 * double(std::clock() - c0) / CLOCKS_PER_SEC / frames;
                    out = gp.read_result();
                    return median(ms);
                };
                Image exact, fast, cpu;
                const double ge = time_gl(PreviewQuality::Exact, exact);
                const double ce = cpu_frame_ms;
                const double gf = time_gl(PreviewQuality::Fast, fast);
                const double cf = cpu_frame_ms;
                std::vector<double> cpu_ms;
                for (int f = 0; cpu_twin && f < std::max(1, frames / 2); ++f) {
                    const double t0 = now_ms();
                    const PreviewLayers layers = composite_layers(s.bg_atlas, s.bg_uv, s.fg_atlas,
                                                                  s.fg_uv, s.alpha, threads);
                    cpu = render_dof(layers, s.depth, lens, threads);
                    cpu_ms.push_back(now_ms() - t0);
                }
                double diff = 0.0, fast_max = 0.0;
                size_t worst = 0;
                for (size_t i = 0; i < exact.size(); ++i) {
                    if (cpu_twin)
                        diff = std::max(diff, double(std::fabs(cpu.pixels[i] - exact.pixels[i])));
                    const double e = std::fabs(fast.pixels[i] - exact.pixels[i]);
                    if (e > fast_max) {
                        fast_max = e;
                        worst = i / 3;
                    }
                }
                std::printf(
                    "%-6.0f %-9s %10.1f %10.1f %9.1f %9.1f %11.1f %10.1f %10.1f %9.1f %11.3f "
                    "%10.2e\n",
                    max_r, blades ? "6 blades" : "circle", ge, gf, 1000.0 / ge, 1000.0 / gf, ce, cf,
                    cpu_twin ? median(cpu_ms) : 0.0, psnr(exact, fast), fast_max, diff);
                if (!dump.empty())
                    std::printf(
                        "  worst fast pixel (%zu, %zu): exact %.3f %.3f %.3f fast %.3f %.3f %.3f\n",
                        worst % w, worst / w, exact.pixels[worst * 3], exact.pixels[worst * 3 + 1],
                        exact.pixels[worst * 3 + 2], fast.pixels[worst * 3],
                        fast.pixels[worst * 3 + 1], fast.pixels[worst * 3 + 2]);
                if (!dump.empty()) {
                    const std::string stem =
                        dump + std::to_string(int(max_r)) + (blades ? "_hex_" : "_circle_");
                    Image d(exact.width, exact.height, 3);
                    for (size_t i = 0; i < d.size(); ++i)
                        d.pixels[i] = std::fabs(fast.pixels[i] - exact.pixels[i]);
                    write_ppm(stem + "exact.ppm", exact);
                    write_ppm(stem + "fast.ppm", fast);
                    write_ppm(stem + "diff.ppm", d, 4.0f);
                }
                if (max_r == 16.0 && blades == 0) {  // per pass, each waited for
                    gp.set_timing(true);
                    std::vector<std::vector<double>> runs;
                    for (int f = 0; f < frames; ++f) {
                        gp.set_frame(s.bg_uv, s.fg_uv, s.alpha);
                        gp.render(lens, PreviewQuality::Fast);
                        passes = gp.pass_times();
                        runs.resize(passes.size());
                        for (size_t k = 0; k < passes.size(); ++k)
                            runs[k].push_back(passes[k].second);
                    }
                    for (size_t k = 0; k < passes.size(); ++k) passes[k].second = median(runs[k]);
                    gp.set_timing(false);
                }
            }
        std::printf("fast path per pass, max_r 16, circle (ms, median):");
        for (const auto& [name, ms] : passes) std::printf("  %s %.1f", name.c_str(), ms);
        std::printf("\n");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "refocus-preview-bench: %s\n", e.what());
        return 1;
    }
    return 0;
}
