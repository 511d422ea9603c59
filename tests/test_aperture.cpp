// The aperture (light-field) renderer and `refocus synth`: blur radius = thin-lens formula for
// circle and blades, agreement with the lens blur layer's pillbox on a plane, exact sharp
// limits, occlusion that a single-layer scatter cannot produce, synth clips on disk.
// torch (glog) defines a CHECK macro too: include it first so that doctest's wins.
#include <torch/torch.h>
// clang-format off
#include <doctest/doctest.h>
// clang-format on

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "io/image_file.h"
#include "ops/lens_blur.h"
#include "render/aperture.h"
#include "synth/synth.h"
#include "test_util.h"
#include "util/error.h"
#include "util/fs.h"

using namespace refocus;

namespace {

constexpr double kPi = 3.14159265358979323846;

ApertureLayer layer(const Image& rgb, float invdepth) {
    ApertureLayer L;
    L.rgb = rgb;
    L.invdepth_const = invdepth;
    return L;
}

// One bright point (total energy 1) at (c, c) on black, at inverse depth 1.
ApertureLayer point_layer(int size, int c) {
    Image img(size, size, 3);
    for (int k = 0; k < 3; ++k) img.at(c, c, k) = 1.0f;
    return layer(img, 1.0f);
}

double bilinear(const Image& img, double x, double y, int ch) {
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const double fx = x - x0, fy = y - y0;
    auto at = [&](int xx, int yy) {
        xx = std::clamp(xx, 0, img.width - 1);
        yy = std::clamp(yy, 0, img.height - 1);
        return static_cast<double>(img.at(xx, yy, ch));
    };
    return (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x0 + 1, y0)) +
           fy * ((1 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1));
}

// Distance from (c, c) along `deg` at which the profile first falls below `level`.
double edge_distance(const Image& img, int c, double deg, double level) {
    const double a = deg * kPi / 180, dx = std::cos(a), dy = std::sin(a);
    double prev = bilinear(img, c, c, 0);
    for (double t = 0.02; t < img.width / 2.0; t += 0.02) {
        const double v = bilinear(img, c + t * dx, c + t * dy, 0);
        if (v < level && prev >= level) return t - 0.02 * (level - v) / (prev - v);
        prev = v;
    }
    return -1;
}

torch::Tensor to_chw(const Image& img) {
    return torch::from_blob(const_cast<float*>(img.data()), {img.height, img.width, img.channels},
                            torch::kFloat)
        .permute({2, 0, 1})
        .contiguous();
}

// A textured test plane: checkers, fine stripes and noise (values in [0.05, 0.95]).
Image texture(int w, int h) {
    Image img = test::pattern_frame(w, h, 0, 5);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            if ((x / 2) % 3 == 0) img.at(x, y, 1) = 0.9f;  // 2-px stripes: fine detail
    return img;
}

}  // namespace

TEST_CASE("a point far out of focus renders a disc of radius aperture*|d - f|") {
    const int size = 64, c = 32;
    ApertureLens lens;
    lens.aperture = 24.0;
    lens.focus = 0.5;  // r = 24 * |1 - 0.5| = 12 px
    const double r = lens.radius(1.0);
    ApertureRenderOptions opts;
    opts.samples_per_px2 = 2.0;
    const auto out = render_aperture({point_layer(size, c)}, lens, opts);
    CHECK(out.max_radius == doctest::Approx(12.0));
    CHECK(out.samples >= static_cast<int>(2 * kPi * r * r));
    double sum = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) sum += out.rgb.at(x, y, 0);
    CHECK(sum == doctest::Approx(1.0).epsilon(1e-4));  // the point's energy is kept
    // Half of the plateau 1/(πr²) marks the edge of the disc.
    const double half = 0.5 / (kPi * r * r);
    int count = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) count += out.rgb.at(x, y, 0) > half;
    const double r_area = std::sqrt(count / kPi);
    MESSAGE("area radius " << r_area << " (r = " << r << ")");
    CHECK(std::abs(r_area - r) < 0.5);
    for (double deg = 0; deg < 360; deg += 22.5) {
        const double e = edge_distance(out.rgb, c, deg, half);
        INFO("direction " << deg << " edge " << e);
        CHECK(std::abs(e - r) < 0.5);
    }
}

TEST_CASE("six blades render a hexagon: radius r along a vertex, r*cos(30 deg) along an edge") {
    const int size = 64, c = 32;
    for (double rot : {0.0, 30.0}) {
        ApertureLens lens;
        lens.aperture = 16.0;
        lens.focus = 0.0;  // r = 16
        lens.shape = ApertureShape::Blades;
        lens.blades = 6;
        lens.rotation_deg = rot;
        const double r = 16.0, apothem = r * std::cos(kPi / 6);
        ApertureRenderOptions opts;
        opts.samples_per_px2 = 2.0;
        const auto out = render_aperture({point_layer(size, c)}, lens, opts);
        const double area = 1.5 * std::sqrt(3.0) * r * r, half = 0.5 / area;
        int count = 0;
        for (int y = 0; y < size; ++y)
            for (int x = 0; x < size; ++x) count += out.rgb.at(x, y, 0) > half;
        const double r_area = std::sqrt(count / (1.5 * std::sqrt(3.0)));
        MESSAGE("rotation " << rot << " area circumradius " << r_area << " (r = " << r << ")");
        CHECK(std::abs(r_area - r) < 0.5);
        double vert = 0, edge = 0;
        for (int k = 0; k < 6; ++k) {
            const double ev = edge_distance(out.rgb, c, rot + 60 * k, half);
            const double ee = edge_distance(out.rgb, c, rot + 30 + 60 * k, half);
            INFO("k " << k << " vertex " << ev << " edge " << ee);
            CHECK(std::abs(ev - r) < 0.5);
            CHECK(std::abs(ee - apothem) < 0.5);
            vert += ev / 6;
            edge += ee / 6;
        }
        CHECK(vert - edge > 1.5);  // 16 − 13.86: the shape is a hexagon, not a disc
    }
}

TEST_CASE("a textured plane at one depth matches the lens blur layer's pillbox") {
    const int w = 96, h = 96;
    const Image tex = texture(w, h);
    for (double r : {2.5, 6.0}) {
        ApertureLens lens;
        lens.aperture = r;
        lens.focus = 0.0;
        const auto out = render_aperture({layer(tex, 1.0f)}, lens);  // default sampling
        LensBlurParams p;
        p.kernel = BlurKernel::Pillbox;
        const torch::Tensor ref =
            lens_blur(to_chw(tex), torch::full({h, w}, static_cast<float>(r)), p);
        const auto acc = ref.accessor<float, 3>();
        // Away from the borders (the two treat them differently): r + 2 px.
        const int b = static_cast<int>(std::ceil(r)) + 2;
        double sum = 0, mx = 0, sum_in = 0;
        int n = 0;
        for (int y = b; y < h - b; ++y)
            for (int x = b; x < w - b; ++x)
                for (int k = 0; k < 3; ++k) {
                    const double d = std::abs(out.rgb.at(x, y, k) - acc[k][y][x]);
                    sum += d;
                    mx = std::max(mx, d);
                    sum_in += std::abs(tex.at(x, y, k) - acc[k][y][x]);
                    ++n;
                }
        MESSAGE("r " << r << " mean |aperture - pillbox| " << sum / n << " max " << mx
                     << " (mean |sharp - pillbox| " << sum_in / n << ")");
        // Tolerance: the renderer's disc is sampled by ~πr² points and bilinear taps (a ~1 px
        // tent); the pillbox has a one-pixel coverage edge. Mean 1%, max 5% of full scale.
        CHECK(sum / n < 0.01);
        CHECK(mx < 0.05);
        CHECK(sum_in / n > 10 * sum / n);  // the blur itself is much larger than the difference
    }
}

TEST_CASE("a small circle of confusion converts to the pillbox radius that reproduces the render") {
    // The renderer reads the layer between pixel centres (bilinearly), which widens a disk of
    // 1-3 px noticeably; kernel_radius_for_coc counts that. The converted radius must reproduce
    // the render better than 8% either side of itself, and for circles under 2 px better than the
    // radius that matches the disk's own moment c²/2 alone (the conversion of earlier builds).
    const int w = 96, h = 96;
    const Image tex = texture(w, h);
    LensBlurParams p;
    p.kernel = BlurKernel::Pillbox;
    for (double c : {1.0, 1.5, 2.5}) {
        ApertureLens lens;
        lens.aperture = c;
        lens.focus = 0.0;
        const auto out = render_aperture({layer(tex, 1.0f)}, lens);
        auto err = [&](double r) {
            const torch::Tensor ref =
                lens_blur(to_chw(tex), torch::full({h, w}, static_cast<float>(r)), p);
            const auto acc = ref.accessor<float, 3>();
            const int b = 6;
            double sum = 0;
            for (int y = b; y < h - b; ++y)
                for (int x = b; x < w - b; ++x)
                    for (int k = 0; k < 3; ++k)
                        sum += std::pow(out.rgb.at(x, y, k) - acc[k][y][x], 2);
            return sum;
        };
        const double r = kernel_radius_for_coc(c, p);
        double lo = 0, hi = c + 2;  // the moment match without the pixel grid's share
        for (int i = 0; i < 40; ++i)
            (lens_blur_second_moment(0.5 * (lo + hi), p) < 0.5 * c * c ? lo : hi) = 0.5 * (lo + hi);
        const double r_old = 0.5 * (lo + hi);
        const double e = err(r), e_old = err(r_old), e_lo = err(0.92 * r), e_hi = err(1.08 * r);
        MESSAGE("coc " << c << " -> pillbox " << r << ": squared error " << e << " (" << r_old
                       << ": " << e_old << ", -8% " << e_lo << ", +8% " << e_hi << ")");
        if (c < 2) CHECK(e < 0.8 * e_old);
        CHECK(e < e_lo);
        CHECK(e < e_hi);
    }
}

TEST_CASE("focus at a layer's depth returns it sharp; aperture 0 returns the composite") {
    const int w = 80, h = 60;
    const Image bg_tex = texture(w, h);
    Image fg_tex(w, h, 3), fg_alpha(w, h, 1);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            fg_tex.at(x, y, 0) = ((x + y) % 3) ? 0.9f : 0.1f;
            fg_tex.at(x, y, 1) = 0.2f;
            fg_tex.at(x, y, 2) = (y % 2) ? 0.7f : 0.3f;
            const double d = std::hypot(x - 40.0, y - 30.0);
            fg_alpha.at(x, y, 0) = static_cast<float>(std::clamp(15.5 - d, 0.0, 1.0));
        }
    ApertureLayer bg = layer(bg_tex, 0.2f), fg = layer(fg_tex, 1.0f);
    fg.alpha = fg_alpha;
    const std::vector<ApertureLayer> scene = {bg, fg};

    SUBCASE("aperture 0: one sample, exactly alpha-over") {
        ApertureLens lens;
        lens.aperture = 0.0;
        lens.focus = 0.6;
        const auto out = render_aperture(scene, lens);
        CHECK(out.samples == 1);
        double mx = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                for (int k = 0; k < 3; ++k) {
                    const float a = fg_alpha.at(x, y, 0);
                    const float want = a * fg_tex.at(x, y, k) + (1 - a) * bg_tex.at(x, y, k);
                    mx = std::max(mx, static_cast<double>(std::abs(out.rgb.at(x, y, k) - want)));
                }
        CHECK(mx < 1e-6);
        // A single layer comes back bit for bit.
        CHECK(test::max_abs_diff(render_aperture({bg}, lens).rgb, bg_tex) == 0.0);
    }
    SUBCASE("focus on the foreground: it is sharp where opaque; the background is blurred") {
        ApertureLens lens;
        lens.aperture = 10.0;  // background r = 8 px
        lens.focus = 1.0;
        const auto out = render_aperture(scene, lens);
        CHECK(out.samples > 100);
        double mx = 0, bg_diff = 0;
        int n = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const bool opaque = fg_alpha.at(x, y, 0) >= 1.0f;
                for (int k = 0; k < 3; ++k) {
                    if (opaque)
                        mx = std::max(mx, static_cast<double>(
                                              std::abs(out.rgb.at(x, y, k) - fg_tex.at(x, y, k))));
                    else if (std::hypot(x - 40.0, y - 30.0) > 25 && x > 10 && x < w - 10)
                        bg_diff += std::abs(out.rgb.at(x, y, k) - bg_tex.at(x, y, k)), ++n;
                }
            }
        CHECK(mx < 1e-6);
        CHECK(bg_diff / n > 0.02);
    }
    SUBCASE("focus on the background: far from the subject it is sharp") {
        ApertureLens lens;
        lens.aperture = 10.0;  // foreground r = 8 px: it reaches 15.5 + 8 + 1 px from its centre
        lens.focus = 0.2;
        const auto out = render_aperture(scene, lens);
        double mx = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                if (std::hypot(x - 40.0, y - 30.0) > 25.5)
                    for (int k = 0; k < 3; ++k)
                        mx = std::max(mx, static_cast<double>(
                                              std::abs(out.rgb.at(x, y, k) - bg_tex.at(x, y, k))));
        CHECK(mx < 1e-6);
    }
}

TEST_CASE("occlusion edge: the aperture renderer sees the background behind a blurred edge") {
    // Sharp green wall (in focus) behind a red square far out of focus (r = 8 px), hard edge.
    const int size = 96, x0 = 28, x1 = 68;  // the square spans [28, 68)²
    Image green(size, size, 3), red(size, size, 3), alpha(size, size, 1), comp(size, size, 3);
    Image radius(size, size, 1);
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            green.at(x, y, 1) = 1.0f;
            red.at(x, y, 0) = 1.0f;
            const bool in = x >= x0 && x < x1 && y >= x0 && y < x1;
            alpha.at(x, y, 0) = in ? 1.0f : 0.0f;
            comp.at(x, y, in ? 0 : 1) = 1.0f;
            radius.at(x, y, 0) = in ? 8.0f : 0.0f;
        }
    ApertureLayer bg = layer(green, 0.0f), fg = layer(red, 1.0f);
    fg.alpha = alpha;
    ApertureLens lens;
    lens.aperture = 8.0;
    lens.focus = 0.0;
    ApertureRenderOptions opts;
    opts.samples_per_px2 = 2.0;
    const auto ap = render_aperture({bg, fg}, lens, opts);
    // The single-layer scatter: the lens blur layer (pillbox) on the sharp composite with the
    // per-pixel radius of the visible surface.
    LensBlurParams p;
    p.kernel = BlurKernel::Pillbox;
    const torch::Tensor scatter = lens_blur(to_chw(comp), to_chw(radius).squeeze(0), p);
    const auto sc = scatter.accessor<float, 3>();
    // Fraction of a disc of radius R cut off by a straight edge at distance d (a circular
    // segment). The square's edge lies half-way between pixels 27 and 28 (bilinear alpha), so
    // pixel 31 is 3.5 px inside it and pixel 25 is 2.5 px outside.
    auto segment = [](double R, double d) {
        return (R * R * std::acos(d / R) - d * std::sqrt(R * R - d * d)) / (kPi * R * R);
    };
    const double seen_in = segment(8, 3.5), spill_out = segment(8, 2.5);  // 0.231, 0.304
    const int y = size / 2;
    const int inside = x0 + 3, outside = x0 - 3;
    MESSAGE("aperture inside G " << ap.rgb.at(inside, y, 1) << " R " << ap.rgb.at(inside, y, 0)
                                 << "; scatter inside G " << sc[1][y][inside] << " R "
                                 << sc[0][y][inside]);
    MESSAGE("aperture outside G " << ap.rgb.at(outside, y, 1) << " R " << ap.rgb.at(outside, y, 0)
                                  << "; scatter outside G " << sc[1][y][outside] << " R "
                                  << sc[0][y][outside]);
    // Inside the edge the lens sees the wall through the blurred square's rim, exactly the
    // part of the aperture whose rays pass beside the square ...
    CHECK(std::abs(ap.rgb.at(inside, y, 1) - seen_in) < 0.015);
    CHECK(std::abs(ap.rgb.at(inside, y, 0) - (1 - seen_in)) < 0.015);
    // ... which the scatter cannot show: no green there, light is lost instead.
    CHECK(sc[1][y][inside] < 0.01);
    CHECK(sc[0][y][inside] + sc[1][y][inside] < 0.85);
    // Outside, the lens's blurred red covers part of the wall; the scatter adds red on top of an
    // unoccluded wall (more light than there is).
    CHECK(std::abs(ap.rgb.at(outside, y, 0) - spill_out) < 0.015);
    CHECK(std::abs(ap.rgb.at(outside, y, 0) + ap.rgb.at(outside, y, 1) - 1.0) < 1e-4);
    CHECK(sc[1][y][outside] > 0.99);
    CHECK(sc[0][y][outside] + sc[1][y][outside] > 1.2);
}

TEST_CASE("sample count follows the largest blur; bad input is refused") {
    ApertureLens lens;
    lens.aperture = 10;
    CHECK(aperture_sample_count(0.0, lens) == 1);
    CHECK(aperture_sample_count(5.0, lens) == static_cast<int>(std::ceil(kPi * 25)));
    CHECK(aperture_sample_count(10.0, lens) == static_cast<int>(std::ceil(kPi * 100)));
    CHECK(aperture_sample_count(0.1, lens) == 16);
    const auto s = aperture_samples(lens, 300);
    CHECK(s.size() == 300);
    double mu = 0, mv = 0;
    for (const auto& p : s) mu += p[0], mv += p[1];
    CHECK(std::abs(mu / s.size()) < 1e-12);
    CHECK(std::abs(mv / s.size()) < 1e-12);
    lens.shape = ApertureShape::Blades;
    lens.blades = 5;
    const auto b = aperture_samples(lens, 300);
    CHECK(b.size() >= 300);
    CHECK(b.size() < 305);

    Image img(8, 8, 3);
    CHECK_THROWS_AS(render_aperture({}, lens), Error);
    ApertureLayer bad = layer(img, 0);
    bad.alpha = Image(7, 8, 1);
    CHECK_THROWS_AS(render_aperture({bad}, lens), Error);
    lens.blades = 2;
    CHECK_THROWS_AS(render_aperture({layer(img, 0)}, lens), Error);
    lens.shape = ApertureShape::Circle;
    lens.aperture = -1;
    CHECK_THROWS_AS(render_aperture({layer(img, 0)}, lens), Error);
    lens.aperture = 1;
    ApertureRenderOptions o;
    o.crop_x = 4;
    o.crop_w = 6;
    CHECK_THROWS_AS(render_aperture({layer(img, 0)}, lens, o), Error);
}

TEST_CASE("synth flow moves the sharp frame onto the next one") {
    SynthOptions o;
    o.scene = "pan";
    o.width = 128;
    o.height = 72;
    o.frames = 6;
    SynthClip clip(o);
    auto f0 = clip.render(2), f1 = clip.render(3);
    // Smooth both frames a little (a linear, shift-invariant filter commutes with a locally
    // uniform motion) so that bilinear interpolation of the finest texture does not dominate.
    for (Image* img : {&f0.sharp, &f1.sharp})
        for (int pass = 0; pass < 2; ++pass) {
            const Image src = *img;
            for (int y = 0; y < src.height; ++y)
                for (int x = 0; x < src.width; ++x)
                    for (int k = 0; k < 3; ++k) {
                        double acc = 0;
                        for (int dy = -1; dy <= 1; ++dy)
                            for (int dx = -1; dx <= 1; ++dx)
                                acc += src.at(std::clamp(x + dx, 0, src.width - 1),
                                              std::clamp(y + dy, 0, src.height - 1), k);
                        img->at(x, y, k) = static_cast<float>(acc / 9);
                    }
        }
    // Mean |sharp_{t+1}(x + flow + delta) - sharp_t(x)| over pixels whose surface is the same
    // at both ends (both fully foreground or both fully background).
    auto warp_error = [&](double ddx, double ddy) {
        double err = 0;
        int n = 0;
        for (int y = 4; y < o.height - 4; ++y)
            for (int x = 4; x < o.width - 4; ++x) {
                const double fx = f0.flow.at(x, y, 0), fy = f0.flow.at(x, y, 1);
                const double tx = x + fx + ddx, ty = y + fy + ddy;
                if (tx < 1 || tx > o.width - 2 || ty < 1 || ty > o.height - 2) continue;
                const float a = f0.alpha.at(x, y, 0);
                const double a1 = bilinear(f1.alpha, tx, ty, 0);
                if (!((a == 0.0f && a1 == 0.0) || (a == 1.0f && a1 == 1.0))) continue;
                for (int k = 0; k < 3; ++k, ++n)
                    err += std::abs(bilinear(f1.sharp, tx, ty, k) - f0.sharp.at(x, y, k));
            }
        return err / n;
    };
    // The ground-truth flow is the best motion: every shift of it by 0.1..0.5 px (a grid)
    // matches worse. (An interpolation floor of ~0.005 remains at the exact flow.)
    const double exact = warp_error(0, 0);
    double best_off = 1e9;
    for (int j = -5; j <= 5; ++j)
        for (int i = -5; i <= 5; ++i)
            if (i || j) best_off = std::min(best_off, warp_error(0.1 * i, 0.1 * j));
    MESSAGE("mean |warped - sharp| at the flow " << exact << ", best 0.1 px-grid shift of it "
                                                 << best_off);
    CHECK(exact < best_off);
    CHECK(exact < 0.7 * warp_error(0.5, 0));
    // The COC pass is the formula applied to the visible surface's inverse depth.
    double mx = 0;
    for (int y = 0; y < o.height; ++y)
        for (int x = 0; x < o.width; ++x)
            mx = std::max(
                mx, std::abs(f0.coc.at(x, y, 0) -
                             clip.aperture() * std::abs(f0.invdepth.at(x, y, 0) - f0.state.focus)));
    CHECK(mx < 1e-4);
}

TEST_CASE("refocus synth writes every pass for each scene, deterministically") {
    auto list = test::cli("synth --scene list");
    CHECK(list.code == 0);
    for (const char* s : {"rack", "walkout", "pan", "hunt", "tripod"})
        CHECK(list.output.find(s) != std::string::npos);
    auto bad = test::cli("synth --scene nope -o " + test::scratch_dir("synth_bad").string());
    CHECK(bad.code != 0);
    CHECK(bad.output.find("unknown scene 'nope'") != std::string::npos);

    for (const char* scene : {"rack", "walkout", "pan", "hunt", "tripod"}) {
        CAPTURE(scene);
        const fs::path a = test::scratch_dir(std::string("synth_") + scene + "_a");
        const fs::path b = test::scratch_dir(std::string("synth_") + scene + "_b");
        const std::string args =
            std::string("synth --quiet --scene ") + scene + " --size 64x36 --frames 8 --seed 7 -o ";
        auto r1 = test::cli(args + a.string());
        REQUIRE_MESSAGE(r1.code == 0, r1.output);
        auto r2 = test::cli(args + b.string());
        REQUIRE_MESSAGE(r2.code == 0, r2.output);

        int count = 0;
        for (const auto& e : fs::directory_iterator(a)) {
            (void)e;
            ++count;
        }
        CHECK(count == 8 * 6 + 1);
        const auto j = nlohmann::json::parse(read_text_file(a / "clip.json"));
        CHECK(j["scene"] == scene);
        CHECK(j["width"] == 64);
        CHECK(j["height"] == 36);
        CHECK(j["frames"] == 8);
        CHECK(j["fps"] == 24.0);
        CHECK(j["seed"] == 7);
        CHECK(j["focus"].size() == 8);
        CHECK(j["lens"]["aperture"].get<double>() > 0);
        CHECK(j["lens"]["radius_formula"].get<std::string>().find("|invdepth - focus|") !=
              std::string::npos);
        const double aperture = j["lens"]["aperture"];
        for (int t = 0; t < 8; ++t) {
            char name[32];
            auto path = [&](const char* pass, const char* ext) {
                std::snprintf(name, sizeof name, "%s_%04d.%s", pass, t, ext);
                return (a / name).string();
            };
            for (const char* pass : {"input", "sharp"}) {
                const auto img = read_image_file(path(pass, "png")).image;
                CHECK(img.width == 64);
                CHECK(img.height == 36);
                CHECK(img.channels == 3);
            }
            const auto coc = read_image_file(path("coc", "exr")).image;
            const auto inv = read_image_file(path("invdepth", "exr")).image;
            const auto alpha = read_image_file(path("alpha", "png"), false).image;
            CHECK(coc.channels == 1);
            CHECK(alpha.channels == 1);
            CHECK((coc.width == 64 && coc.height == 36 && alpha.width == 64 && alpha.height == 36));
            // clip.json's formula reproduces the COC pass.
            const double focus = j["focus"][t];
            double mx = 0;
            for (size_t i = 0; i < coc.size(); ++i)
                mx = std::max(mx,
                              std::abs(coc.pixels[i] - aperture * std::abs(inv.pixels[i] - focus)));
            CHECK(mx < 1e-4);
            auto in = OIIO::ImageInput::open(path("flow", "exr"));
            REQUIRE(in);
            CHECK(in->spec().nchannels == 2);
            CHECK(in->spec().width == 64);
            CHECK(in->spec().height == 36);
            std::vector<float> flow(64 * 36 * 2);
            CHECK(in->read_image(0, 0, 0, 2, OIIO::TypeDesc::FLOAT, flow.data()));
            in->close();
            double fmax = 0;
            for (float v : flow) fmax = std::max(fmax, static_cast<double>(std::abs(v)));
            if (t == 7)
                CHECK(fmax == 0.0);  // no frame after the last
            else if (std::string(scene) == "pan")
                CHECK(fmax > 0.1);
        }
        // Same seed, same bytes (EXR: same pixels; OpenEXR headers carry a capture date).
        for (const auto& e : fs::directory_iterator(a)) {
            const auto other = b / e.path().filename();
            REQUIRE(fs::exists(other));
            if (e.path().extension() != ".exr") {
                CHECK_MESSAGE(read_text_file(e.path()) == read_text_file(other), e.path().string());
                continue;
            }
            std::vector<float> pa, pb;
            for (auto [p, v] : {std::pair{e.path(), &pa}, {other, &pb}}) {
                auto in = OIIO::ImageInput::open(p.string());
                REQUIRE(in);
                const auto& sp = in->spec();
                v->resize(static_cast<size_t>(sp.width) * sp.height * sp.nchannels);
                CHECK(in->read_image(0, 0, 0, sp.nchannels, OIIO::TypeDesc::FLOAT, v->data()));
            }
            CHECK_MESSAGE(pa == pb, e.path().string());
        }
    }
    // Another seed, another clip.
    const fs::path c = test::scratch_dir("synth_rack_seed8");
    REQUIRE(
        test::cli("synth --quiet --scene rack --size 64x36 --frames 2 --seed 8 -o " + c.string())
            .code == 0);
    CHECK(read_text_file(c / "sharp_0000.png") !=
          read_text_file(fs::path(REFOCUS_TEST_TMP) / "synth_rack_b" / "sharp_0000.png"));
}
