// The aperture (light-field) renderer; see aperture.h for the model and the conventions.
#include "render/aperture.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "util/error.h"

namespace refocus {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kGoldenAngle = 2.39996322972865332;  // π(3 − √5)
constexpr double kNoBlurPx = 1e-3;                    // below this a frame is sharp

// Area of the unit aperture shape (circumradius 1).
double unit_shape_area(const ApertureLens& lens) {
    if (lens.shape == ApertureShape::Circle) return kPi;
    const int n = lens.blades;
    return 0.5 * n * std::sin(2.0 * kPi / n);
}

void check_lens(const ApertureLens& lens) {
    if (!std::isfinite(lens.aperture) || lens.aperture < 0.0)
        throw Error("aperture renderer: aperture must be finite and >= 0 (got " +
                    std::to_string(lens.aperture) + ")");
    if (!std::isfinite(lens.focus))
        throw Error("aperture renderer: focus must be a finite inverse depth");
    if (lens.shape == ApertureShape::Blades && lens.blades < 3)
        throw Error("aperture renderer: a bladed aperture needs >= 3 blades (got " +
                    std::to_string(lens.blades) + ")");
}

// A layer prepared for sampling: premultiplied RGBA and the shift map s = A·(d − f).
struct PreparedLayer {
    int w = 0, h = 0;
    std::vector<float> rgba;   // [h][w][4], premultiplied
    std::vector<float> shift;  // [h][w]; empty: `shift_const`
    float shift_const = 0.0f;
    // Bounding box of alpha > 0 in layer pixels, grown by the largest |shift| + 1: an output
    // pixel outside it cannot see this layer under any aperture sample.
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;
};

inline void bilinear4(const PreparedLayer& L, float px, float py, float out[4]) {
    const float fx0 = std::floor(px), fy0 = std::floor(py);
    const float fx = px - fx0, fy = py - fy0;
    const int xa = std::clamp(static_cast<int>(fx0), 0, L.w - 1);
    const int xb = std::clamp(static_cast<int>(fx0) + 1, 0, L.w - 1);
    const int ya = std::clamp(static_cast<int>(fy0), 0, L.h - 1);
    const int yb = std::clamp(static_cast<int>(fy0) + 1, 0, L.h - 1);
    const float* p00 = &L.rgba[(static_cast<size_t>(ya) * L.w + xa) * 4];
    const float* p10 = &L.rgba[(static_cast<size_t>(ya) * L.w + xb) * 4];
    const float* p01 = &L.rgba[(static_cast<size_t>(yb) * L.w + xa) * 4];
    const float* p11 = &L.rgba[(static_cast<size_t>(yb) * L.w + xb) * 4];
    const float w00 = (1 - fx) * (1 - fy), w10 = fx * (1 - fy), w01 = (1 - fx) * fy, w11 = fx * fy;
    for (int c = 0; c < 4; ++c) out[c] = w00 * p00[c] + w10 * p10[c] + w01 * p01[c] + w11 * p11[c];
}

inline float bilinear1(const std::vector<float>& m, int w, int h, float px, float py) {
    const float fx0 = std::floor(px), fy0 = std::floor(py);
    const float fx = px - fx0, fy = py - fy0;
    const int xa = std::clamp(static_cast<int>(fx0), 0, w - 1);
    const int xb = std::clamp(static_cast<int>(fx0) + 1, 0, w - 1);
    const int ya = std::clamp(static_cast<int>(fy0), 0, h - 1);
    const int yb = std::clamp(static_cast<int>(fy0) + 1, 0, h - 1);
    const float* r0 = &m[static_cast<size_t>(ya) * w];
    const float* r1 = &m[static_cast<size_t>(yb) * w];
    return (1 - fy) * ((1 - fx) * r0[xa] + fx * r0[xb]) + fy * ((1 - fx) * r1[xa] + fx * r1[xb]);
}

void check_layers(const std::vector<ApertureLayer>& layers) {
    if (layers.empty()) throw Error("aperture renderer: no layers");
    const int w = layers[0].rgb.width, h = layers[0].rgb.height;
    if (w <= 0 || h <= 0) throw Error("aperture renderer: layer 0 has an empty rgb image");
    for (size_t i = 0; i < layers.size(); ++i) {
        const auto& L = layers[i];
        const std::string name = "aperture renderer: layer " + std::to_string(i) + " ";
        if (L.rgb.channels != 3)
            throw Error(name + "rgb needs 3 channels (has " + std::to_string(L.rgb.channels) + ")");
        if (L.rgb.width != w || L.rgb.height != h)
            throw Error(name + "is " + std::to_string(L.rgb.width) + "x" +
                        std::to_string(L.rgb.height) + ", layer 0 is " + std::to_string(w) + "x" +
                        std::to_string(h));
        for (const Image* m : {&L.alpha, &L.invdepth}) {
            if (m->empty()) continue;
            const char* what = m == &L.alpha ? "alpha" : "invdepth";
            if (m->channels != 1 || m->width != w || m->height != h)
                throw Error(name + what + " must be " + std::to_string(w) + "x" +
                            std::to_string(h) + "x1 (is " + std::to_string(m->width) + "x" +
                            std::to_string(m->height) + "x" + std::to_string(m->channels) + ")");
        }
        if (L.invdepth.empty() && !std::isfinite(L.invdepth_const))
            throw Error(name + "invdepth_const is not finite");
    }
}

PreparedLayer prepare(const ApertureLayer& L, const ApertureLens& lens) {
    PreparedLayer P;
    P.w = L.rgb.width;
    P.h = L.rgb.height;
    const size_t n = static_cast<size_t>(P.w) * P.h;
    P.rgba.resize(n * 4);
    float max_shift = 0.0f;
    if (L.invdepth.empty()) {
        P.shift_const = static_cast<float>(lens.aperture * (L.invdepth_const - lens.focus));
        max_shift = std::abs(P.shift_const);
    } else {
        P.shift.resize(n);
        for (size_t i = 0; i < n; ++i) {
            const float d = L.invdepth.pixels[i];
            if (!std::isfinite(d)) throw Error("aperture renderer: non-finite inverse depth");
            P.shift[i] = static_cast<float>(lens.aperture * (d - lens.focus));
            max_shift = std::max(max_shift, std::abs(P.shift[i]));
        }
    }
    int bx0 = P.w, by0 = P.h, bx1 = -1, by1 = -1;
    for (int y = 0; y < P.h; ++y)
        for (int x = 0; x < P.w; ++x) {
            const size_t i = static_cast<size_t>(y) * P.w + x;
            const float a = L.alpha.empty() ? 1.0f : std::clamp(L.alpha.pixels[i], 0.0f, 1.0f);
            const float k = L.premultiplied ? 1.0f : a;
            for (int c = 0; c < 3; ++c) P.rgba[i * 4 + c] = L.rgb.pixels[i * 3 + c] * k;
            P.rgba[i * 4 + 3] = a;
            if (a > 0.0f) {
                bx0 = std::min(bx0, x);
                by0 = std::min(by0, y);
                bx1 = std::max(bx1, x);
                by1 = std::max(by1, y);
            }
        }
    if (bx1 >= 0) {
        const int grow = static_cast<int>(std::ceil(max_shift)) + 1;
        P.x0 = bx0 - grow;
        P.y0 = by0 - grow;
        P.x1 = bx1 + grow;
        P.y1 = by1 + grow;
    }
    return P;
}

}  // namespace

double ApertureLens::radius(double invdepth) const {
    return aperture * std::abs(invdepth - focus);
}

bool inside_aperture(const ApertureLens& lens, double u, double v) {
    if (lens.shape == ApertureShape::Circle) return u * u + v * v <= 1.0;
    const int n = lens.blades;
    const double apothem = std::cos(kPi / n);
    const double rot = lens.rotation_deg * kPi / 180.0;
    // Edge k joins vertices k and k+1; its outward normal points half-way between them.
    for (int k = 0; k < n; ++k) {
        const double psi = rot + 2.0 * kPi * (k + 0.5) / n;
        if (u * std::cos(psi) + v * std::sin(psi) > apothem + 1e-12) return false;
    }
    return true;
}

std::vector<std::array<double, 2>> aperture_samples(const ApertureLens& lens, int count) {
    check_lens(lens);
    if (count <= 1) return {{0.0, 0.0}};
    auto spiral = [&](int m) {
        std::vector<std::array<double, 2>> pts;
        pts.reserve(m);
        for (int i = 0; i < m; ++i) {
            const double r = std::sqrt((i + 0.5) / m), t = i * kGoldenAngle;
            const double u = r * std::cos(t), v = r * std::sin(t);
            if (inside_aperture(lens, u, v)) pts.push_back({u, v});
        }
        return pts;
    };
    std::vector<std::array<double, 2>> pts;
    if (lens.shape == ApertureShape::Circle) {
        pts = spiral(count);
    } else {
        // Points of a spiral over the circumscribed disc that fall inside the polygon: uniform
        // density in the polygon, equal weights. Grow the spiral until `count` are inside.
        int m = static_cast<int>(count * kPi / unit_shape_area(lens));
        do pts = spiral(m++);
        while (static_cast<int>(pts.size()) < count);
    }
    // Zero mean: the blur of a point is centred on it (as the lens blur layer's disc is).
    double mu = 0, mv = 0;
    for (const auto& p : pts) mu += p[0], mv += p[1];
    mu /= pts.size();
    mv /= pts.size();
    for (auto& p : pts) p[0] -= mu, p[1] -= mv;
    return pts;
}

int aperture_sample_count(double max_radius, const ApertureLens& lens,
                          const ApertureRenderOptions& opts) {
    if (opts.samples > 0) return opts.samples;
    if (!(max_radius >= kNoBlurPx)) return 1;
    const double want = opts.samples_per_px2 * unit_shape_area(lens) * max_radius * max_radius;
    const double capped = std::min<double>(opts.max_samples, std::ceil(want));
    return std::max(1, std::max(opts.min_samples, static_cast<int>(capped)));
}

double max_blur_radius(const std::vector<ApertureLayer>& layers, const ApertureLens& lens) {
    double r = 0.0;
    for (const auto& L : layers) {
        const size_t n = static_cast<size_t>(L.rgb.width) * L.rgb.height;
        for (size_t i = 0; i < n; ++i) {
            if (!L.alpha.empty() && !(L.alpha.pixels[i] > 0.0f)) continue;
            const double d = L.invdepth.empty() ? L.invdepth_const : L.invdepth.pixels[i];
            r = std::max(r, lens.radius(d));
            if (L.invdepth.empty()) break;  // one value for the whole layer
        }
    }
    return r;
}

ApertureRender render_aperture(const std::vector<ApertureLayer>& layers, const ApertureLens& lens,
                               const ApertureRenderOptions& opts) {
    check_lens(lens);
    check_layers(layers);
    const int lw = layers[0].rgb.width, lh = layers[0].rgb.height;
    const int cw = opts.crop_w > 0 ? opts.crop_w : lw - opts.crop_x;
    const int ch = opts.crop_h > 0 ? opts.crop_h : lh - opts.crop_y;
    if (opts.crop_x < 0 || opts.crop_y < 0 || cw <= 0 || ch <= 0 || opts.crop_x + cw > lw ||
        opts.crop_y + ch > lh)
        throw Error("aperture renderer: crop window " + std::to_string(cw) + "x" +
                    std::to_string(ch) + "+" + std::to_string(opts.crop_x) + "+" +
                    std::to_string(opts.crop_y) + " is outside the " + std::to_string(lw) + "x" +
                    std::to_string(lh) + " layers");

    ApertureRender out;
    out.max_radius = max_blur_radius(layers, lens);
    out.samples = aperture_sample_count(out.max_radius, lens, opts);
    const auto samples = aperture_samples(lens, out.samples);
    out.samples = static_cast<int>(samples.size());
    const float weight = 1.0f / samples.size();
    std::vector<float> su(samples.size()), sv(samples.size());
    for (size_t i = 0; i < samples.size(); ++i) {
        su[i] = static_cast<float>(samples[i][0]);
        sv[i] = static_cast<float>(samples[i][1]);
    }

    std::vector<PreparedLayer> prep;
    prep.reserve(layers.size());
    for (const auto& L : layers) prep.push_back(prepare(L, lens));
    const int nl = static_cast<int>(prep.size());
    const int iters = std::max(0, opts.fixed_point_iterations);

    out.rgb = Image(cw, ch, 3);
    out.alpha = Image(cw, ch, 1);
#pragma omp parallel for schedule(dynamic, 2)
    for (int oy = 0; oy < ch; ++oy) {
        const int y = oy + opts.crop_y;
        std::vector<int> active;  // layers this row's pixels can see, front first
        active.reserve(nl);
        for (int ox = 0; ox < cw; ++ox) {
            const int x = ox + opts.crop_x;
            active.clear();
            for (int l = nl - 1; l >= 0; --l) {
                const auto& P = prep[l];
                if (x >= P.x0 && x <= P.x1 && y >= P.y0 && y <= P.y1) active.push_back(l);
            }
            double acc[4] = {0, 0, 0, 0};
            for (size_t s = 0; s < su.size(); ++s) {
                const float u = su[s], v = sv[s];
                float c[3] = {0, 0, 0};
                float trans = 1.0f;  // transmittance of the layers in front so far
                for (int l : active) {
                    const auto& P = prep[l];
                    // Backward warp: the source p with x = p + s(p)·(u, v).
                    float sh =
                        P.shift.empty() ? P.shift_const : P.shift[static_cast<size_t>(y) * P.w + x];
                    float px = x - sh * u, py = y - sh * v;
                    if (!P.shift.empty()) {
                        for (int k = 0; k < iters; ++k) {
                            sh = bilinear1(P.shift, P.w, P.h, px, py);
                            px = x - sh * u;
                            py = y - sh * v;
                        }
                    }
                    float smp[4];
                    bilinear4(P, px, py, smp);
                    // Front-to-back "over" with premultiplied colour.
                    c[0] += trans * smp[0];
                    c[1] += trans * smp[1];
                    c[2] += trans * smp[2];
                    trans *= 1.0f - smp[3];
                    if (trans <= 1e-6f) break;  // opaque: nothing behind is seen
                }
                acc[0] += c[0];
                acc[1] += c[1];
                acc[2] += c[2];
                acc[3] += 1.0f - trans;
            }
            for (int k = 0; k < 3; ++k) out.rgb.at(ox, oy, k) = static_cast<float>(acc[k] * weight);
            out.alpha.at(ox, oy, 0) = static_cast<float>(acc[3] * weight);
        }
    }
    return out;
}

}  // namespace refocus
