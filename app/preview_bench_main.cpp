// refocus-preview-bench: the real-time preview's frame time at 512×288, GLSL on OSMesa
// (llvmpipe: this machine's software GL) beside the CPU twin (engine/render/preview.cpp), for
// max radius 8 and 16, circle and 6 blades. A frame = composite (paper eq. 1) + layered depth
// of field (prep, tiles, gather per layer), with the frame's UV/alpha upload on the GL side.
// Usage: refocus-preview-bench [--frames N] [--size WxH] [--threads T]
#include <GL/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
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
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--frames" && i + 1 < argc) {
            frames = std::max(1, std::atoi(argv[++i]));
        } else if (a == "--size" && i + 1 < argc) {
            if (std::sscanf(argv[++i], "%dx%d", &w, &h) != 2 || w < 1 || h < 1) {
                std::fprintf(stderr, "refocus-preview-bench: --size needs WxH\n");
                return 2;
            }
        } else if (a == "--threads" && i + 1 < argc) {
            threads = std::max(1, std::atoi(argv[++i]));
        } else {
            std::fprintf(stderr,
                         "usage: refocus-preview-bench [--frames N] [--size WxH] "
                         "[--threads T]\n");
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
        std::printf("%-8s %-9s %12s %12s %9s %12s\n", "max_r", "aperture", "GLSL ms", "CPU ms",
                    "CPU/GLSL", "max |diff|");
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
                std::vector<double> gl_ms, cpu_ms;
                Image cpu;
                for (int f = 0; f <= frames; ++f) {  // frame 0: warm-up (shader JIT, tables)
                    const double t0 = now_ms();
                    gp.set_frame(s.bg_uv, s.fg_uv, s.alpha);
                    gp.render(lens);
                    glFinish();
                    const double t1 = now_ms();
                    if (f > 0) gl_ms.push_back(t1 - t0);
                }
                const Image gpu = gp.read_result();
                for (int f = 0; f < std::max(1, frames / 2); ++f) {
                    const double t0 = now_ms();
                    const PreviewLayers layers = composite_layers(s.bg_atlas, s.bg_uv, s.fg_atlas,
                                                                  s.fg_uv, s.alpha, threads);
                    cpu = render_dof(layers, s.depth, lens, threads);
                    cpu_ms.push_back(now_ms() - t0);
                }
                double diff = 0.0;
                for (size_t i = 0; i < cpu.size(); ++i)
                    diff = std::max(diff, double(std::fabs(cpu.pixels[i] - gpu.pixels[i])));
                const double g = median(gl_ms), c = median(cpu_ms);
                std::printf("%-8.0f %-9s %12.1f %12.1f %9.2f %12.2e\n", max_r,
                            blades ? "6 blades" : "circle", g, c, c / g, diff);
            }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "refocus-preview-bench: %s\n", e.what());
        return 1;
    }
    return 0;
}
