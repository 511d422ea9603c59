// Procedural misfocused clips with exact ground truth; see synth.h.
#include "synth/synth.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "io/image_file.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRefHeight = 180.0;  // scene units are px of the 320x180 reference

// ---- deterministic hashing (independent of thread order and of the standard library) ----

inline uint32_t mix(uint32_t x) {
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}
inline uint32_t hash(uint32_t seed, int a, int b = 0, int c = 0) {
    uint32_t h = mix(seed ^ 0x9e3779b9U);
    h = mix(h ^ (static_cast<uint32_t>(a) * 0x8da6b343U));
    h = mix(h ^ (static_cast<uint32_t>(b) * 0xd8163841U));
    h = mix(h ^ (static_cast<uint32_t>(c) * 0xcb1ab31fU));
    return h;
}
inline double unit(uint32_t h) {
    return (h >> 8) * (1.0 / 16777216.0);
}

double smoothstep(double a, double b, double x) {
    const double t = std::clamp((x - a) / (b - a), 0.0, 1.0);
    return t * t * (3 - 2 * t);
}
double lerp(double a, double b, double t) {
    return a + (b - a) * t;
}

// Value noise on the integer lattice, smooth in between; fbm of a few octaves.
double value_noise(uint32_t seed, double x, double y) {
    const double fx = std::floor(x), fy = std::floor(y);
    const int ix = static_cast<int>(fx), iy = static_cast<int>(fy);
    double tx = x - fx, ty = y - fy;
    tx = tx * tx * (3 - 2 * tx);
    ty = ty * ty * (3 - 2 * ty);
    const double a = unit(hash(seed, ix, iy)), b = unit(hash(seed, ix + 1, iy));
    const double c = unit(hash(seed, ix, iy + 1)), d = unit(hash(seed, ix + 1, iy + 1));
    return lerp(lerp(a, b, tx), lerp(c, d, tx), ty);
}
double fbm(uint32_t seed, double x, double y, int octaves) {
    double s = 0, amp = 0.5, norm = 0;
    for (int o = 0; o < octaves; ++o) {
        s += amp * value_noise(seed + 101 * o, x, y);
        norm += amp;
        amp *= 0.5;
        x *= 2.03;
        y *= 2.03;
    }
    return s / norm;
}
// Smooth 1-D noise in [-1, 1] for camera shake and focus jitter.
double noise1(uint32_t seed, double t) {
    const double f = std::floor(t);
    double u = t - f;
    u = u * u * (3 - 2 * u);
    const int i = static_cast<int>(f);
    return 2 * lerp(unit(hash(seed, i)), unit(hash(seed, i + 1)), u) - 1;
}

struct Rgb {
    double r, g, b;
};
Rgb mixc(const Rgb& a, const Rgb& b, double t) {
    return {lerp(a.r, b.r, t), lerp(a.g, b.g, t), lerp(a.b, b.b, t)};
}
Rgb scale(const Rgb& a, double k) {
    return {a.r * k, a.g * k, a.b * k};
}

// A saturated-ish linear colour from a hash, with value in [lo, hi].
Rgb palette(uint32_t h, double lo, double hi) {
    const double hue = unit(h) * 6.0, sat = 0.35 + 0.5 * unit(mix(h + 1));
    const double v = lerp(lo, hi, unit(mix(h + 2)));
    const int i = static_cast<int>(hue) % 6;
    const double f = hue - std::floor(hue);
    const double p = v * (1 - sat), q = v * (1 - sat * f), t = v * (1 - sat * (1 - f));
    switch (i) {
        case 0:
            return {v, t, p};
        case 1:
            return {q, v, p};
        case 2:
            return {p, v, t};
        case 3:
            return {p, q, v};
        case 4:
            return {t, p, v};
        default:
            return {v, p, q};
    }
}

// Text-like glyphs: 5x7 bitmaps in 6x9 cells of `k` units, 48 distinct "letters" per seed,
// words separated by spaces. Returns ink coverage (0/1) at (x, y) (units, relative to the block).
bool glyph_ink(uint32_t seed, double x, double y, double k) {
    const double cx = x / (6 * k), cy = y / (9 * k);
    const int ci = static_cast<int>(std::floor(cx)), cj = static_cast<int>(std::floor(cy));
    const uint32_t cell = hash(seed, ci, cj, 7);
    if (cell % 6 == 0) return false;  // a space
    const int gx = static_cast<int>((cx - ci) * 6), gy = static_cast<int>((cy - cj) * 9) - 1;
    if (gx >= 5 || gy < 0 || gy >= 7) return false;  // spacing between letters and lines
    const int letter = static_cast<int>((cell >> 8) % 48);
    // Letters are strokes: a vertical stem, a bar and a few random pixels.
    const uint32_t shape = hash(seed, letter, 0, 11);
    if ((shape & 1) && gx == static_cast<int>((shape >> 1) % 3) * 2) return true;
    if ((shape & 8) && gy == static_cast<int>((shape >> 4) % 4) * 2) return true;
    return (hash(seed, letter, gx, gy) & 7) < 2;
}

// The background wall at texture coordinates (u, v), reference px: panels of patterns.
Rgb wall(uint32_t seed, double u, double v) {
    constexpr double kPanelW = 74, kPanelH = 52, kGap = 3;
    const int pj = static_cast<int>(std::floor(v / kPanelH));
    const double uo = u + (pj & 1) * kPanelW * 0.5;  // brick offset
    const int pi = static_cast<int>(std::floor(uo / kPanelW));
    const double lu = uo - pi * kPanelW, lv = v - pj * kPanelH;
    // Slow shading across the wall so that no panel is flat.
    const double shade = 0.7 + 0.6 * fbm(seed + 5, u / 90.0, v / 90.0, 2);
    const Rgb mortar = scale({0.30, 0.28, 0.25}, shade);
    if (lu < kGap || lv < kGap) return mortar;
    const double x = lu - kGap, y = lv - kGap;  // inside the panel
    const uint32_t h = hash(seed, pi, pj, 3);
    const Rgb c1 = palette(h, 0.45, 0.85), c2 = palette(mix(h ^ 0x55), 0.02, 0.15);
    Rgb c;
    switch (h % 7) {
        case 0:    // small text, dark ink on light paper
        case 1: {  // larger text, light on dark
            const double k = (h % 7 == 0) ? 1.0 : 1.5 + (h >> 12) % 2;
            const bool ink = glyph_ink(seed ^ h, x - 2, y - 2, k);
            c = (h % 7 == 0) ? (ink ? c2 : c1) : (ink ? c1 : c2);
            break;
        }
        case 2: {  // checkers, 2..6 px
            const double cell = 2 + (h >> 9) % 5;
            const int a =
                static_cast<int>(std::floor(x / cell)) + static_cast<int>(std::floor(y / cell));
            c = (a & 1) ? c1 : c2;
            break;
        }
        case 3: {  // stripes at several periods and angles
            const double periods[] = {3, 4, 6, 10};
            const double angles[] = {0, 90, 45, -30};
            const double per = periods[(h >> 9) % 4], ang = angles[(h >> 13) % 4] * kPi / 180;
            const double s = x * std::cos(ang) + y * std::sin(ang);
            c = (std::fmod(std::abs(s), per) < per * 0.5) ? c1 : c2;
            break;
        }
        case 4: {  // coloured noise (a natural-looking texture)
            const double n = fbm(seed ^ h, x / 3.0, y / 3.0, 4);
            c = mixc(c2, c1, std::clamp(1.6 * n - 0.3, 0.0, 1.0));
            break;
        }
        case 5: {  // Siemens star: every frequency at once
            const double dx = x - (kPanelW - kGap) / 2, dy = y - (kPanelH - kGap) / 2;
            const double a = std::atan2(dy, dx);
            c = (std::sin(a * 18) > 0) ? c1 : c2;
            if (dx * dx + dy * dy > 22 * 22) c = mixc(c1, c2, 0.5);
            break;
        }
        default: {  // bold text line over a checker (mixed scales)
            const bool ink = glyph_ink(seed ^ h, x - 3, y - 3, 2.5);
            const int a = static_cast<int>(std::floor(x / 3)) + static_cast<int>(std::floor(y / 3));
            c = ink ? c2 : ((a & 1) ? c1 : scale(c1, 0.7));
            break;
        }
    }
    return scale(c, shade);
}

// The subject in its own coordinates (reference px at inverse depth 1, origin at its centre):
// signed distance to its silhouette (head + neck + torso; negative inside).
double subject_sdf(double x, double y) {
    const double head = std::hypot(x, y + 38) - 15;
    auto box = [](double px, double py, double hx, double hy, double r) {
        const double qx = std::abs(px) - hx + r, qy = std::abs(py) - hy + r;
        return std::hypot(std::max(qx, 0.0), std::max(qy, 0.0)) + std::min(std::max(qx, qy), 0.0) -
               r;
    };
    const double neck = box(x, y + 20, 6, 6, 2);
    const double torso = box(x, y + 20 - 52 + 2, 28, 40, 12);
    return std::min({head, neck, torso});
}

Rgb subject_color(uint32_t seed, double x, double y) {
    const Rgb skin = {0.55, 0.33, 0.22}, shirt1 = palette(hash(seed, 77), 0.35, 0.8),
              shirt2 = palette(hash(seed, 78), 0.02, 0.12);
    if (y < -22) {  // head: skin with pores, eyes, mouth, hair
        Rgb c = scale(skin, 0.8 + 0.4 * fbm(seed + 9, x / 1.5, y / 1.5, 3));
        if (y < -46 + 0.02 * x * x)
            c = scale({0.08, 0.05, 0.03}, 0.7 + 0.6 * value_noise(seed, x * 1.3, y / 4));
        if (std::hypot(std::abs(x) - 5.5, y + 40) < 1.8) c = {0.02, 0.02, 0.03};
        if (std::abs(y + 31) < 0.8 && std::abs(x) < 5) c = {0.25, 0.05, 0.05};
        return c;
    }
    if (y < -12) return scale(skin, 0.75);  // neck
    // Shirt: fine stripes, a badge of small text, a checked pocket.
    Rgb c = (std::fmod(y + 100, 5.0) < 2.5) ? shirt1 : scale(shirt1, 0.55);
    if (x > -22 && x < 2 && y > -2 && y < 16)
        c = glyph_ink(seed + 3, x + 22, y + 2, 1.0) ? Rgb{0.02, 0.02, 0.02} : Rgb{0.8, 0.8, 0.75};
    if (x > 8 && x < 22 && y > 24 && y < 40)
        c = ((static_cast<int>(std::floor(x / 2)) + static_cast<int>(std::floor(y / 2))) & 1)
                ? shirt2
                : shirt1;
    return c;
}

struct SceneDef {
    const char* name;
    const char* description;
};
const SceneDef kScenes[] = {
    {"rack",
     "rack focus: focus pulls from the far wall to the subject (inverse depth 0.22 -> 1.0)"},
    {"walkout",
     "a subject walks away out of the focal plane (its inverse depth 1.05 -> 0.42, "
     "focus fixed at 1.0)"},
    {"pan", "camera pan with fixed focus on the far wall; the subject stays blurred; parallax"},
    {"hunt", "autofocus hunting: focus oscillates around the subject with decaying amplitude"},
    {"tripod",
     "locked-off camera, static subject, focus sweeps wall -> subject -> wall (focus breathing "
     "on a tripod: every depth is sharp in some frame)"},
    {"pillar",
     "the camera trucks sideways past a pillar standing in front of the wall (both background: "
     "parallax within a layer that no homography explains); focus racks wall -> subject"},
};

int scene_index(const std::string& name) {
    for (int i = 0; i < static_cast<int>(std::size(kScenes)); ++i)
        if (name == kScenes[i].name) return i;
    std::string known;
    for (const auto& s : kScenes) known += std::string(known.empty() ? "" : ", ") + s.name;
    throw Error("unknown scene '" + name + "' (known: " + known + ")");
}

const char* kFormula = "r_px = aperture * |invdepth - focus|";

}  // namespace

const std::vector<SynthSceneInfo>& synth_scenes() {
    static const std::vector<SynthSceneInfo> list = [] {
        std::vector<SynthSceneInfo> v;
        for (const auto& s : kScenes) v.push_back({s.name, s.description});
        return v;
    }();
    return list;
}

SynthClip::SynthClip(const SynthOptions& opts) : m_opts(opts) {
    scene_index(opts.scene);
    if (opts.width < 8 || opts.height < 8 || opts.width > 8192 || opts.height > 8192)
        throw Error("synth: size must be between 8x8 and 8192x8192 (got " +
                    std::to_string(opts.width) + "x" + std::to_string(opts.height) + ")");
    if (opts.frames < 1 || opts.frames > 100000)
        throw Error("synth: frames must be >= 1 (got " + std::to_string(opts.frames) + ")");
    if (!(opts.fps > 0)) throw Error("synth: fps must be > 0");
    m_scale = opts.height / kRefHeight;
    m_aperture = (opts.scene == "hunt" ? 10.0 : 11.0) * m_scale;
    // The margin covers the largest blur anywhere in the clip (plus the bilinear footprint), so
    // that every aperture sample of a visible pixel lands on rendered layer content.
    double rmax = 0;
    const double nearest_bg = opts.scene == "pillar" ? kPillarInvdepth : m_d_bottom;
    for (int t = 0; t < opts.frames; ++t) {
        const auto s = state(t);
        for (double d : {s.fg_invdepth, m_d_top, m_d_bottom, nearest_bg})
            rmax = std::max(rmax, m_aperture * std::abs(d - s.focus));
    }
    m_margin = static_cast<int>(std::ceil(rmax * 1.05)) + 2;
}

bool SynthClip::on_pillar(double x, const SynthFrameState& st) const {
    const double u = (x - st.pan * kPillarInvdepth - st.shake_x) / m_scale;  // reference px
    return std::abs(u - kPillarU) < 0.5 * kPillarWidth;
}

double SynthClip::bg_invdepth(double y) const {
    return m_d_top + (m_d_bottom - m_d_top) * (y + 0.5) / m_opts.height;
}

SynthFrameState SynthClip::state(int t) const {
    const double W = m_opts.width, H = m_opts.height, S = m_scale;
    const double tau = m_opts.frames > 1 ? static_cast<double>(t) / (m_opts.frames - 1) : 0.0;
    const double sec = t / m_opts.fps;
    const uint32_t seed = m_opts.seed;
    const double phase = 2 * kPi * unit(hash(seed, 500));
    SynthFrameState s;
    // Handheld rotation: ~1 px of smooth wobble (depth-independent).
    const double shake = (m_opts.scene == "pan" ? 0.4 : m_opts.scene == "tripod" ? 0.0 : 1.0) * S;
    s.shake_x = shake * noise1(seed + 17, sec * 3.0);
    s.shake_y = shake * noise1(seed + 29, sec * 3.0);
    if (m_opts.scene == "rack") {
        s.focus = lerp(0.22, 1.0, smoothstep(0.25, 0.75, tau));
        s.fg_invdepth = 1.0;
        s.fg_x = W * (0.62 + 0.02 * std::sin(2 * kPi * 0.8 * tau + phase));
        s.fg_y = H * 0.56;
        s.pan = S * (-10 + 20 * tau);
    } else if (m_opts.scene == "walkout") {
        s.focus = 1.0;
        s.fg_invdepth = lerp(1.05, 0.42, smoothstep(0.05, 0.95, tau));
        s.fg_x = W * (0.36 + 0.3 * tau);
        // Walking away: the subject rises towards the horizon as it shrinks, with a step bob.
        s.fg_y = H * (0.3 + 0.26 * s.fg_invdepth) -
                 1.5 * S * s.fg_invdepth * std::abs(std::sin(2 * kPi * 1.2 * sec + phase));
        s.pan = 0;
    } else if (m_opts.scene == "pan") {
        s.focus = 0.2;
        s.fg_invdepth = 0.85;
        s.fg_x = W * (0.75 - 0.5 * tau);
        s.fg_y = H * 0.57;
        s.pan = S * (-60 + 120 * tau);
    } else if (m_opts.scene == "pillar") {
        s.focus = lerp(0.3, 1.0, smoothstep(0.2, 0.8, tau));
        s.fg_invdepth = 1.0;
        s.fg_x = W * 0.72;
        s.fg_y = H * 0.56;
        s.pan = S * (-30 + 60 * tau);
    } else if (m_opts.scene == "tripod") {
        const double tri = 1.0 - std::abs(2.0 * tau - 1.0);  // 0 → 1 → 0
        s.focus = lerp(0.15, 1.0, tri);
        s.fg_invdepth = 0.95;
        s.fg_x = W * 0.5;
        s.fg_y = H * 0.57;
        s.pan = 0;
    } else {  // hunt
        const double swing = 0.5 * (1 - 0.55 * tau) * std::sin(2 * kPi * 2.5 * tau + phase);
        s.focus = std::clamp(0.95 + swing + 0.04 * noise1(seed + 41, sec * 4), 0.4, 1.5);
        s.fg_invdepth = 0.95;
        s.fg_x = W * (0.45 + 0.1 * tau);
        s.fg_y = H * 0.57;
        s.pan = S * (-4 + 8 * tau);
    }
    return s;
}

ApertureLens SynthClip::lens(int t) const {
    ApertureLens L;
    L.aperture = m_aperture;
    L.focus = state(t).focus;
    L.shape = m_opts.shape;
    L.blades = m_opts.blades;
    L.rotation_deg = m_opts.rotation_deg;
    return L;
}

std::vector<ApertureLayer> SynthClip::layers(int t) const {
    const auto st = state(t);
    const int m = m_margin, lw = m_opts.width + 2 * m, lh = m_opts.height + 2 * m;
    const double S = m_scale;
    // Each scene gets its own wall and subject for a seed.
    const uint32_t seed = hash(m_opts.seed, scene_index(m_opts.scene), 0, 0x5eed);
    ApertureLayer bg, fg;
    bg.rgb = Image(lw, lh, 3);
    bg.invdepth = Image(lw, lh, 1);
    fg.rgb = Image(lw, lh, 3);
    fg.alpha = Image(lw, lh, 1);
    fg.invdepth_const = static_cast<float>(st.fg_invdepth);
    const double fscale = S * st.fg_invdepth;  // subject px per subject unit (perspective)
    const double fcx = st.fg_x + st.pan * st.fg_invdepth + st.shake_x;
    const double fcy = st.fg_y + st.shake_y;
    const double feather = 1.2;  // px: the soft alpha edge
    const bool pillar = m_opts.scene == "pillar";
    // 3x3 supersampling of the textures (box filter): fine detail without aliasing.
    constexpr int kSS = 3;
#pragma omp parallel for schedule(dynamic, 4)
    for (int Y = 0; Y < lh; ++Y) {
        for (int X = 0; X < lw; ++X) {
            const double x = X - m, y = Y - m;  // screen px
            // Background: the wall row is fixed to the surface, so its depth moves with shake_y.
            const double d = bg_invdepth(y - st.shake_y);
            // The pillar (scene "pillar") occludes the wall where a ray meets it.
            const bool pillar_px = pillar && on_pillar(x, st);
            bg.invdepth.at(X, Y, 0) = static_cast<float>(pillar_px ? kPillarInvdepth : d);
            Rgb acc = {0, 0, 0}, facc = {0, 0, 0};
            for (int sy = 0; sy < kSS; ++sy)
                for (int sx = 0; sx < kSS; ++sx) {
                    const double ox = (sx + 0.5) / kSS - 0.5, oy = (sy + 0.5) / kSS - 0.5;
                    const double v = (y + oy - st.shake_y) / S;
                    const bool hit = pillar && on_pillar(x + ox, st);
                    const double u =
                        (x + ox - st.pan * (hit ? kPillarInvdepth : d) - st.shake_x) / S;
                    const Rgb c = hit ? wall(seed ^ 0x9111a5u, 2 * u, 2 * v) : wall(seed, u, v);
                    acc = {acc.r + c.r, acc.g + c.g, acc.b + c.b};
                    const Rgb f =
                        subject_color(seed, (x + ox - fcx) / fscale, (y + oy - fcy) / fscale);
                    facc = {facc.r + f.r, facc.g + f.g, facc.b + f.b};
                }
            const double n = kSS * kSS;
            bg.rgb.at(X, Y, 0) = static_cast<float>(acc.r / n);
            bg.rgb.at(X, Y, 1) = static_cast<float>(acc.g / n);
            bg.rgb.at(X, Y, 2) = static_cast<float>(acc.b / n);
            fg.rgb.at(X, Y, 0) = static_cast<float>(facc.r / n);
            fg.rgb.at(X, Y, 1) = static_cast<float>(facc.g / n);
            fg.rgb.at(X, Y, 2) = static_cast<float>(facc.b / n);
            const double sd = subject_sdf((x - fcx) / fscale, (y - fcy) / fscale) * fscale;
            fg.alpha.at(X, Y, 0) = static_cast<float>(std::clamp(0.5 - sd / feather, 0.0, 1.0));
        }
    }
    return {bg, fg};
}

SynthFrame SynthClip::render(int t) const {
    SynthFrame f;
    f.state = state(t);
    const auto L = layers(t);
    const auto lens = this->lens(t);
    ApertureRenderOptions ro;
    ro.crop_x = ro.crop_y = m_margin;
    ro.crop_w = m_opts.width;
    ro.crop_h = m_opts.height;
    // Aperture samples per px² of the 320x180 reference, not of this clip: a larger clip is the
    // same scene on a finer grid (textures and blur scale with it), so samples one reference px
    // apart serve it as they serve the reference. Per px² of its own, 1080p would take hours.
    ro.samples_per_px2 = 1.0 / std::max(1.0, m_scale * m_scale);
    auto blurred = render_aperture(L, lens, ro);
    f.input = std::move(blurred.rgb);
    f.samples = blurred.samples;
    f.max_radius = 0;
    ApertureLens pin = lens;
    pin.aperture = 0;  // a pinhole: the exact sharp composite (one sample)
    f.sharp = render_aperture(L, pin, ro).rgb;

    const int W = m_opts.width, H = m_opts.height, m = m_margin;
    const bool last = t + 1 >= m_opts.frames;
    const auto next = state(t + 1);
    const auto& st = f.state;
    f.coc = Image(W, H, 1);
    f.alpha = Image(W, H, 1);
    f.flow = Image(W, H, 2);
    f.invdepth = Image(W, H, 1);
    const double fscale = m_scale * st.fg_invdepth, nscale = m_scale * next.fg_invdepth;
    const double fcx = st.fg_x + st.pan * st.fg_invdepth + st.shake_x, fcy = st.fg_y + st.shake_y;
    const double ncx = next.fg_x + next.pan * next.fg_invdepth + next.shake_x,
                 ncy = next.fg_y + next.shake_y;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const float a = L[1].alpha.at(x + m, y + m, 0);
            f.alpha.at(x, y, 0) = a;
            double d, fx, fy;
            if (a >= 0.5f) {  // the visible surface is the subject: its point q moves with it
                d = st.fg_invdepth;
                const double qx = (x - fcx) / fscale, qy = (y - fcy) / fscale;
                fx = ncx + qx * nscale - x;
                fy = ncy + qy * nscale - y;
            } else {  // the wall: pan parallax at its own depth plus the rotation
                d = L[0].invdepth.at(x + m, y + m, 0);
                fx = (next.pan - st.pan) * d + (next.shake_x - st.shake_x);
                fy = next.shake_y - st.shake_y;
            }
            f.invdepth.at(x, y, 0) = static_cast<float>(d);
            const double r = lens.radius(d);
            f.coc.at(x, y, 0) = static_cast<float>(r);
            f.max_radius = std::max(f.max_radius, r);
            f.flow.at(x, y, 0) = last ? 0.0f : static_cast<float>(fx);
            f.flow.at(x, y, 1) = last ? 0.0f : static_cast<float>(fy);
        }
    return f;
}

std::string SynthClip::clip_json() const {
    using nlohmann::json;
    json j;
    j["version"] = 1;
    j["generator"] = "refocus synth";
    j["scene"] = m_opts.scene;
    j["description"] = kScenes[scene_index(m_opts.scene)].description;
    j["width"] = m_opts.width;
    j["height"] = m_opts.height;
    j["frames"] = m_opts.frames;
    j["fps"] = m_opts.fps;
    j["seed"] = m_opts.seed;
    json lens;
    lens["model"] = "thin lens (seed 001 eq. 1.12): blur radius linear in inverse depth";
    lens["radius_formula"] = kFormula;
    lens["aperture"] = m_aperture;
    lens["aperture_unit"] = "px of blur radius per unit of inverse depth";
    lens["shape"] = m_opts.shape == ApertureShape::Circle ? "circle" : "blades";
    if (m_opts.shape == ApertureShape::Blades) {
        lens["blades"] = m_opts.blades;
        lens["rotation_deg"] = m_opts.rotation_deg;
        lens["radius_is"] = "circumradius (a vertex lies at r)";
    }
    lens["renderer"] =
        "aperture (light-field) renderer, engine/render/aperture.h: layers warped per aperture "
        "sample, composited front to back, averaged";
    j["lens"] = lens;
    json focus = json::array(), fgd = json::array(), pan = json::array(), shake = json::array();
    for (int t = 0; t < m_opts.frames; ++t) {
        const auto s = state(t);
        focus.push_back(s.focus);
        fgd.push_back(s.fg_invdepth);
        pan.push_back(s.pan);
        shake.push_back({s.shake_x, s.shake_y});
    }
    j["focus"] = focus;
    j["foreground"] = {
        {"invdepth", fgd}, {"alpha_edge_px", 1.2}, {"size", "proportional to its inverse depth"}};
    j["background"] = {
        {"invdepth_top", m_d_top},
        {"invdepth_bottom", m_d_bottom},
        {"invdepth_formula", "invdepth(y) = top + (bottom - top) * (y - shake_y + 0.5) / height"}};
    if (m_opts.scene == "pillar")
        j["background"]["pillar"] = {
            {"invdepth", kPillarInvdepth},
            {"u_center", kPillarU},
            {"width", kPillarWidth},
            {"meaning",
             "a full-height band of the background layer in front of the wall, at "
             "screen x = u * H/180 + pan * invdepth + shake_x (u in px of the "
             "320x180 reference)"}};
    j["camera"] = {{"pan", pan},
                   {"pan_meaning", "a point at inverse depth d is displaced pan * d px in x"},
                   {"shake_px", shake},
                   {"shake_meaning", "rotation: displaces every depth alike"}};
    j["files"] = {{"input", "input_%04d.png"}, {"sharp", "sharp_%04d.png"},
                  {"coc", "coc_%04d.exr"},     {"alpha", "alpha_%04d.png"},
                  {"flow", "flow_%04d.exr"},   {"invdepth", "invdepth_%04d.exr"}};
    j["passes"] = {{"input", "misfocused frames, sRGB 8-bit, rendered by the aperture renderer"},
                   {"sharp", "all-in-focus composite, sRGB 8-bit"},
                   {"coc",
                    "blur radius px of the visible surface of the sharp frame (foreground where "
                    "alpha >= 0.5), 1 channel float"},
                   {"alpha", "foreground alpha, linear 8-bit (not sRGB)"},
                   {"flow",
                    "forward optical flow t -> t+1 of the visible surface, px, channels (dx, dy); "
                    "the last frame's flow is zero"},
                   {"invdepth", "inverse depth of the visible surface, 1 channel float"}};
    return j.dump(2) + "\n";
}

std::vector<std::string> write_synth_clip(const SynthOptions& opts, const std::string& dir,
                                          const std::function<void(int)>& progress) {
    SynthClip clip(opts);
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (!fs::is_directory(dir)) throw Error(file_error(dir, "cannot create the output folder"));
    std::vector<std::string> files;
    auto name = [&](const char* pass, int t, const char* ext) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%s_%04d.%s", pass, t, ext);
        return (fs::path(dir) / buf).string();
    };
    for (int t = 0; t < clip.frames(); ++t) {
        const SynthFrame f = clip.render(t);
        const std::pair<std::string, std::function<void(const std::string&)>> outs[] = {
            {name("input", t, "png"),
             [&](const std::string& p) { write_image_file(p, f.input, PixelFormat::Png8); }},
            {name("sharp", t, "png"),
             [&](const std::string& p) { write_image_file(p, f.sharp, PixelFormat::Png8); }},
            {name("coc", t, "exr"),
             [&](const std::string& p) { write_image_file(p, f.coc, PixelFormat::ExrFloat); }},
            {name("alpha", t, "png"),
             [&](const std::string& p) { write_image_file(p, f.alpha, PixelFormat::Png8, false); }},
            {name("flow", t, "exr"),
             [&](const std::string& p) { write_image_file(p, f.flow, PixelFormat::ExrFloat); }},
            {name("invdepth", t, "exr"),
             [&](const std::string& p) { write_image_file(p, f.invdepth, PixelFormat::ExrFloat); }},
        };
        for (const auto& [path, write] : outs) {
            write(path);
            files.push_back(path);
        }
        if (progress) progress(t);
    }
    const std::string json_path = (fs::path(dir) / "clip.json").string();
    write_file_atomic(json_path, clip.clip_json());
    files.push_back(json_path);
    return files;
}

Image coc_heatmap(const Image& coc, double max_radius) {
    // Turbo colour map (Mikhailov 2019), polynomial fit; values are sRGB, decoded to linear.
    auto turbo = [](double x, float out[3]) {
        x = std::clamp(x, 0.0, 1.0);
        const double r =
            0.13572138 +
            x * (4.61539260 +
                 x * (-42.66032258 + x * (132.13108234 + x * (-152.94239396 + x * 59.28637943))));
        const double g =
            0.09140261 +
            x * (2.19418839 +
                 x * (4.84296658 + x * (-14.18503333 + x * (4.27729857 + x * 2.82956604))));
        const double b =
            0.10667330 +
            x * (12.64194608 +
                 x * (-60.58204836 + x * (110.36276771 + x * (-89.90310912 + x * 27.34824973))));
        out[0] = srgb_to_linear(static_cast<float>(std::clamp(r, 0.0, 1.0)));
        out[1] = srgb_to_linear(static_cast<float>(std::clamp(g, 0.0, 1.0)));
        out[2] = srgb_to_linear(static_cast<float>(std::clamp(b, 0.0, 1.0)));
    };
    Image out(coc.width, coc.height, 3);
    const double k = max_radius > 0 ? 1.0 / max_radius : 0.0;
    for (int y = 0; y < coc.height; ++y)
        for (int x = 0; x < coc.width; ++x) turbo(coc.at(x, y, 0) * k, &out.at(x, y, 0));
    return out;
}

Image synth_triplet(const SynthFrame& f, double max_radius, int gap) {
    const int w = f.input.width, h = f.input.height;
    Image out(3 * w + 2 * gap, h, 3, 1.0f);
    const Image heat = coc_heatmap(f.coc, max_radius);
    const Image* parts[] = {&f.input, &f.sharp, &heat};
    for (int i = 0; i < 3; ++i)
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                for (int c = 0; c < 3; ++c) out.at(i * (w + gap) + x, y, c) = parts[i]->at(x, y, c);
    return out;
}

}  // namespace refocus
