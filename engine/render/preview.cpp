// The real-time preview's CPU twin; see preview.h for the equations. Every function here has a
// GLSL counterpart in shaders/ with the same name in the comment, the same float operations in
// the same order, so that tests/gl/test_gl_preview.cpp can hold them to float rounding.
#include "render/preview.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <thread>

#include "util/error.h"

namespace refocus {

namespace {

constexpr double kPi = 3.14159265358979323846;

// preview_lib.glsl finite_or_zero: an exponent of all ones is Inf or NaN (bit test, so that no
// fast-math assumption can fold it away on either side).
inline float finite_or_zero(float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    return (bits & 0x7f800000u) == 0x7f800000u ? 0.0f : v;
}

inline bool is_finite(float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    return (bits & 0x7f800000u) != 0x7f800000u;
}

inline float clamp01(float v) {
    return std::min(std::max(v, 0.0f), 1.0f);
}

// Runs body(y0, y1) over row ranges on `threads` threads.
template <class F>
void parallel_rows(int height, int threads, F&& body) {
    threads = std::max(1, std::min(threads, height));
    if (threads == 1) {
        body(0, height);
        return;
    }
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t) {
        const int y0 = height * t / threads, y1 = height * (t + 1) / threads;
        pool.emplace_back([&body, y0, y1] { body(y0, y1); });
    }
    for (auto& th : pool) th.join();
}

// preview_lib.glsl atlas_coord: u ∈ [−1, 1] (align_corners = false) → clamped texel coordinate.
inline void atlas_coord(float u, int n, int& i0, int& i1, float& f) {
    float x = ((finite_or_zero(u) + 1.0f) * static_cast<float>(n) - 1.0f) * 0.5f;
    x = std::min(std::max(x, 0.0f), static_cast<float>(n - 1));
    const float fl = std::floor(x);
    i0 = static_cast<int>(fl);
    i1 = std::min(i0 + 1, n - 1);
    f = x - fl;
}

// preview_lib.glsl sample_atlas: bilinear over sanitised texels.
inline void sample_atlas(const Image& atlas, float u, float v, float out[3]) {
    int x0, x1, y0, y1;
    float fx, fy;
    atlas_coord(u, atlas.width, x0, x1, fx);
    atlas_coord(v, atlas.height, y0, y1, fy);
    for (int c = 0; c < 3; ++c) {
        const float a00 = finite_or_zero(atlas.at(x0, y0, c));
        const float a10 = finite_or_zero(atlas.at(x1, y0, c));
        const float a01 = finite_or_zero(atlas.at(x0, y1, c));
        const float a11 = finite_or_zero(atlas.at(x1, y1, c));
        const float top = a00 * (1.0f - fx) + a10 * fx;
        const float bot = a01 * (1.0f - fx) + a11 * fx;
        out[c] = top * (1.0f - fy) + bot * fy;
    }
}

void check_image(const Image& img, int w, int h, int channels, const char* what) {
    if (img.width != w || img.height != h || img.channels != channels)
        throw Error(std::string("preview: ") + what + " is " + std::to_string(img.width) + "x" +
                    std::to_string(img.height) + "x" + std::to_string(img.channels) +
                    ", expected " + std::to_string(w) + "x" + std::to_string(h) + "x" +
                    std::to_string(channels));
}

// dof_prep.frag, one layer: P0 = (a·c', r), P1 = (a, 1/K(r)).
struct PreparedLayer {
    std::vector<float> p0;  // [h][w][4]
    std::vector<float> p1;  // [h][w][2]
};

PreparedLayer prepare_layer(const Image& colour, const Image* alpha, const Image& invdepth,
                            float invdepth_const, const PreviewLens& lens,
                            const std::vector<float>& area, int threads) {
    const int w = colour.width, h = colour.height;
    PreparedLayer L;
    L.p0.resize(static_cast<size_t>(w) * h * 4);
    L.p1.resize(static_cast<size_t>(w) * h * 2);
    const float gain = static_cast<float>(lens.highlight_gain);
    const float threshold = static_cast<float>(lens.highlight_threshold);
    const int last = static_cast<int>(area.size()) - 1;
    parallel_rows(h, threads, [&](int y0, int y1) {
        for (int y = y0; y < y1; ++y)
            for (int x = 0; x < w; ++x) {
                float c[3];
                for (int k = 0; k < 3; ++k) c[k] = finite_or_zero(colour.at(x, y, k));
                const float a = alpha ? clamp01(finite_or_zero(alpha->at(x, y, 0))) : 1.0f;
                const float d = invdepth.empty() ? invdepth_const : invdepth.at(x, y, 0);
                const float r = preview_radius(d, lens);
                const float lum = 0.2126f * c[0] + 0.7152f * c[1] + 0.0722f * c[2];
                const float boost =
                    1.0f + gain * std::max(lum - threshold, 0.0f) * clamp01(r - 0.5f);
                const float xr = r * static_cast<float>(kPreviewAreaSteps);
                const float fl = std::floor(xr);
                const int i = std::min(static_cast<int>(fl), last - 1);
                const float f = xr - fl;
                const float kar = area[i] * (1.0f - f) + area[i + 1] * f;
                const size_t o = static_cast<size_t>(y) * w + x;
                for (int k = 0; k < 3; ++k) L.p0[o * 4 + k] = finite_or_zero(c[k] * boost) * a;
                L.p0[o * 4 + 3] = r;
                L.p1[o * 2 + 0] = a;
                L.p1[o * 2 + 1] = 1.0f / kar;
            }
    });
    return L;
}

// dof_tiles.frag: the largest r among the pixels that can reach each tile.
std::vector<float> tile_max(const PreparedLayer& L, int w, int h, int window, int& tw, int& th) {
    const int t = kPreviewTileSize;
    tw = (w + t - 1) / t;
    th = (h + t - 1) / t;
    std::vector<float> tiles(static_cast<size_t>(tw) * th, 0.0f);
    for (int ty = 0; ty < th; ++ty)
        for (int tx = 0; tx < tw; ++tx) {
            const int x0 = std::max(tx * t - window, 0),
                      x1 = std::min(tx * t + t - 1 + window, w - 1);
            const int y0 = std::max(ty * t - window, 0),
                      y1 = std::min(ty * t + t - 1 + window, h - 1);
            float m = 0.0f;
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x)
                    m = std::max(m, L.p0[(static_cast<size_t>(y) * w + x) * 4 + 3]);
            tiles[static_cast<size_t>(ty) * tw + tx] = m;
        }
    return tiles;
}

// dof.frag gather for one pixel: out = (F̂, Â).
inline void gather(const PreparedLayer& L, int w, int h, int px, int py, float rwin, int window,
                   const std::vector<float>& shape, float beta, float out[4]) {
    const int half = static_cast<int>(std::floor(rwin + 0.5f));
    const size_t op = static_cast<size_t>(py) * w + px;
    if (half == 0) {  // early pass-through: nothing within reach is blurred
        for (int k = 0; k < 3; ++k) out[k] = L.p0[op * 4 + k];
        out[3] = L.p1[op * 2 + 0];
        return;
    }
    const int side = 2 * window + 1;
    float sr = 0.0f, sg = 0.0f, sb = 0.0f, sa = 0.0f, sw = 0.0f;
    // Taps with dx² + dy² ≥ (R + ½)² add exactly 0 (ρ_n ≥ ρ): skip them per row.
    const float reach2 = (rwin + 0.5f) * (rwin + 0.5f);
    for (int dy = -half; dy <= half; ++dy) {
        const int qy = py + dy;
        if (qy < 0 || qy >= h) continue;
        const int span = std::min(
            half, static_cast<int>(std::sqrt(std::max(reach2 - float(dy * dy), 0.0f))) + 1);
        for (int dx = -span; dx <= span; ++dx) {
            const int qx = px + dx;
            if (qx < 0 || qx >= w) continue;
            const size_t oq = static_cast<size_t>(qy) * w + qx;
            const float* p0 = &L.p0[oq * 4];
            const float* p1 = &L.p1[oq * 2];
            // offset o = p − q = (−dx, −dy)
            const float rho = shape[static_cast<size_t>(window - dy) * side + (window - dx)];
            const float rq = p0[3];
            const float edge = rq - rho + 0.5f;
            if (edge <= 0.0f) continue;
            const float wgt = disk_kernel(rq - rho, beta) * std::min(edge, 1.0f) * p1[1];
            sr += wgt * p0[0];
            sg += wgt * p0[1];
            sb += wgt * p0[2];
            sa += wgt * p1[0];
            sw += wgt;
        }
    }
    out[0] = sr / sw;
    out[1] = sg / sw;
    out[2] = sb / sw;
    out[3] = sa / sw;
}

}  // namespace

void check_preview_lens(const PreviewLens& lens) {
    auto bad = [](const std::string& what) { throw Error("preview lens: " + what); };
    if (!std::isfinite(lens.aperture) || lens.aperture < 0.0)
        bad("aperture must be finite and >= 0 (got " + std::to_string(lens.aperture) + ")");
    if (!std::isfinite(lens.focus)) bad("focus must be a finite inverse depth");
    if (!std::isfinite(lens.beta) || lens.beta <= 1.0 / std::exp(1.0))
        bad("beta must be > 1/e (got " + std::to_string(lens.beta) + ")");
    if (!std::isfinite(lens.highlight_threshold)) bad("highlight_threshold must be finite");
    if (!std::isfinite(lens.highlight_gain) || lens.highlight_gain < 0.0)
        bad("highlight_gain must be finite and >= 0 (got " + std::to_string(lens.highlight_gain) +
            ")");
    if (lens.blades != 0 && (lens.blades < 3 || lens.blades > 64))
        bad("blades must be 0 (circle) or 3..64 (got " + std::to_string(lens.blades) + ")");
    if (!std::isfinite(lens.rotation_deg)) bad("rotation_deg must be finite");
    if (!std::isfinite(lens.max_radius) || lens.max_radius < 0.0 ||
        lens.max_radius > kPreviewMaxRadius)
        bad("max_radius must be in [0, " + std::to_string(kPreviewMaxRadius) + "] (got " +
            std::to_string(lens.max_radius) + ")");
}

float disk_kernel(float d, float beta) {
    if (d > 0.0f) return 1.0f / (1.0f - d * std::exp(-beta * d));
    const float e = std::exp(beta * d);
    return e / (e - d);
}

int preview_window(const PreviewLens& lens) {
    return static_cast<int>(std::floor(lens.max_radius + 0.5));
}

std::vector<float> preview_shape_table(const PreviewLens& lens) {
    const int window = preview_window(lens), side = 2 * window + 1;
    std::vector<float> shape(static_cast<size_t>(side) * side);
    const double n = lens.blades;
    const double rot = lens.rotation_deg * kPi / 180.0;
    for (int oy = -window; oy <= window; ++oy)
        for (int ox = -window; ox <= window; ++ox) {
            double rho = std::sqrt(double(ox) * ox + double(oy) * oy);
            if (lens.blades >= 3 && rho > 0.0) {
                const double sector = 2.0 * kPi / n;
                const double phi = std::atan2(double(oy), double(ox)) - rot;
                const double local = phi - sector * std::floor(phi / sector);
                rho *= std::cos(local - kPi / n) / std::cos(kPi / n);
            }
            shape[static_cast<size_t>(oy + window) * side + (ox + window)] =
                static_cast<float>(rho);
        }
    return shape;
}

std::vector<float> preview_area_table(const PreviewLens& lens, const std::vector<float>& shape) {
    const int count = static_cast<int>(std::ceil(lens.max_radius * kPreviewAreaSteps)) + 2;
    const float beta = static_cast<float>(lens.beta);
    std::vector<float> area(count);
    for (int i = 0; i < count; ++i) {
        const float r = static_cast<float>(i) / kPreviewAreaSteps;
        double sum = 0.0;
        for (float rho : shape) {
            const float edge = r - rho + 0.5f;
            if (edge <= 0.0f) continue;
            sum += double(disk_kernel(r - rho, beta)) * std::min(edge, 1.0f);
        }
        area[i] = static_cast<float>(sum);
    }
    return area;
}

void preview_atlas_coord(float u, int n, int& i0, int& i1, float& f) {
    atlas_coord(u, n, i0, i1, f);
}

float preview_radius(float invdepth, const PreviewLens& lens) {
    const float r =
        static_cast<float>(lens.aperture) * std::fabs(invdepth - static_cast<float>(lens.focus));
    if (!is_finite(r)) return 0.0f;
    return std::min(r, static_cast<float>(lens.max_radius));
}

PreviewLayers composite_layers(const Image& background_atlas, const Image& background_uv,
                               const Image& foreground_atlas, const Image& foreground_uv,
                               const Image& alpha, int threads, const Image& background_fix,
                               const Image& foreground_fix) {
    if (background_atlas.empty() || background_atlas.channels < 3)
        throw Error("preview: the background atlas needs >= 3 channels");
    if (background_uv.empty() || background_uv.channels != 2)
        throw Error("preview: the background UV map needs 2 channels");
    const int w = background_uv.width, h = background_uv.height;
    const bool has_fg = !foreground_atlas.empty();
    if (has_fg) {
        if (foreground_atlas.channels < 3)
            throw Error("preview: the foreground atlas needs >= 3 channels");
        check_image(foreground_uv, w, h, 2, "foreground UV map");
        check_image(alpha, w, h, 1, "alpha map");
    }
    const bool bg_fix = !background_fix.empty(), fg_fix = has_fg && !foreground_fix.empty();
    if (bg_fix) check_image(background_fix, w, h, 3, "background fix");
    if (fg_fix) check_image(foreground_fix, w, h, 3, "foreground fix");
    PreviewLayers out;
    out.composite = Image(w, h, 3);
    out.background = Image(w, h, 3);
    out.foreground = Image(w, h, 3);
    out.alpha = Image(w, h, 1);
    // composite.frag
    parallel_rows(h, threads, [&](int y0, int y1) {
        for (int y = y0; y < y1; ++y)
            for (int x = 0; x < w; ++x) {
                float b[3], f[3] = {0.0f, 0.0f, 0.0f};
                sample_atlas(background_atlas, background_uv.at(x, y, 0), background_uv.at(x, y, 1),
                             b);
                float a = 0.0f;
                if (has_fg) {
                    sample_atlas(foreground_atlas, foreground_uv.at(x, y, 0),
                                 foreground_uv.at(x, y, 1), f);
                    a = clamp01(finite_or_zero(alpha.at(x, y, 0)));
                }
                for (int c = 0; c < 3; ++c) {
                    if (bg_fix) b[c] += finite_or_zero(background_fix.at(x, y, c));
                    if (fg_fix) f[c] += finite_or_zero(foreground_fix.at(x, y, c));
                    out.composite.at(x, y, c) = a * f[c] + (1.0f - a) * b[c];  // eq. 1
                    out.background.at(x, y, c) = b[c];
                    out.foreground.at(x, y, c) = f[c];
                }
                out.alpha.at(x, y, 0) = a;
            }
    });
    return out;
}

Image render_dof(const PreviewLayers& layers, const PreviewDepth& depth, const PreviewLens& lens,
                 int threads) {
    check_preview_lens(lens);
    const int w = layers.background.width, h = layers.background.height;
    if (layers.background.empty()) throw Error("preview: empty background layer");
    check_image(layers.background, w, h, 3, "background layer");
    check_image(layers.foreground, w, h, 3, "foreground layer");
    check_image(layers.alpha, w, h, 1, "alpha layer");
    if (!depth.background.empty())
        check_image(depth.background, w, h, 1, "background inverse depth");
    if (!depth.foreground.empty())
        check_image(depth.foreground, w, h, 1, "foreground inverse depth");

    const std::vector<float> shape = preview_shape_table(lens);
    const std::vector<float> area = preview_area_table(lens, shape);
    const int window = preview_window(lens);
    const float beta = static_cast<float>(lens.beta);

    const PreparedLayer bg = prepare_layer(layers.background, nullptr, depth.background,
                                           depth.background_const, lens, area, threads);
    const PreparedLayer fg = prepare_layer(layers.foreground, &layers.alpha, depth.foreground,
                                           depth.foreground_const, lens, area, threads);
    int tw, th;
    const std::vector<float> bg_tiles = tile_max(bg, w, h, window, tw, th);
    const std::vector<float> fg_tiles = tile_max(fg, w, h, window, tw, th);

    Image out(w, h, 3);
    parallel_rows(h, threads, [&](int y0, int y1) {
        for (int y = y0; y < y1; ++y)
            for (int x = 0; x < w; ++x) {
                const size_t tile =
                    static_cast<size_t>(y / kPreviewTileSize) * tw + x / kPreviewTileSize;
                float b[4], f[4];
                gather(bg, w, h, x, y, bg_tiles[tile], window, shape, beta, b);
                gather(fg, w, h, x, y, fg_tiles[tile], window, shape, beta, f);
                // dof.frag over: out = F̂ + (1 − Â)·B̂
                for (int c = 0; c < 3; ++c) out.at(x, y, c) = f[c] + (1.0f - f[3]) * b[c];
            }
    });
    return out;
}

}  // namespace refocus
