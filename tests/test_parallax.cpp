// Parallax within a layer (synth scene "pillar"): a pillar stands in front of the wall, both in
// the background layer, and the camera trucks past them. No homography carries the layer from
// frame to frame, so the shared atlas cannot explain the pillar in every frame: the fit must
// still beat the shot, never be worse than it on the pillar, and say where it is unsure.
#include <torch/torch.h>

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "test_util.h"

using namespace refocus;

namespace {

// Masks of frame t from the clip's ground truth: the pillar (inverse depth 0.8, not the
// subject) and the wall well away from it (at least `gap` px from any pillar pixel).
struct Regions {
    Image pillar, wall;
};

Regions regions(const Image& invdepth, const Image& alpha, int gap) {
    const int W = invdepth.width, H = invdepth.height;
    Regions r{Image(W, H, 1, 0.0f), Image(W, H, 1, 0.0f)};
    std::vector<int> pillar_cols;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const bool bg = alpha.pixels[(y * W + x) * alpha.channels] < 0.5f;
            const bool p =
                bg && std::abs(invdepth.pixels[(y * W + x) * invdepth.channels] - 0.8f) < 0.02f;
            r.pillar.pixels[y * W + x] = p ? 1.0f : 0.0f;
            if (p && y == H / 2) pillar_cols.push_back(x);
        }
    REQUIRE(!pillar_cols.empty());
    const int x0 = pillar_cols.front() - gap, x1 = pillar_cols.back() + gap;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const bool bg = alpha.pixels[(y * W + x) * alpha.channels] < 0.5f;
            const bool near_subject = alpha.pixels[(y * W + x) * alpha.channels] > 0.0f;
            r.wall.pixels[y * W + x] =
                bg && !near_subject && (x < x0 || x > x1) && x >= gap && x < W - gap ? 1.0f : 0.0f;
        }
    return r;
}

double masked_mean(const Image& m, const Image& mask) {
    double s = 0, n = 0;
    for (size_t p = 0; p < mask.pixels.size(); ++p) {
        s += mask.pixels[p] * m.pixels[p * m.channels];
        n += mask.pixels[p];
    }
    return n > 0 ? s / n : 0.0;
}

}  // namespace

TEST_CASE("parallax within a layer: the fit beats the shot and the confidence pass marks it") {
    test::TinyClip c = test::make_tiny("parallax_pillar", "pillar", "160x90");
    const int T = 8;
    // The sharper-view rule off: the clip is made with the model's kernel, and at 160x90 no
    // frame sees the wall 2 px sharper than another. The default is checked on the same fit below.
    auto r = test::cli("fit '" + c.project.string() +
                       "' --iters 200 --set fit.sharper_view_px=0 --coc '" +
                       (c.clip / "coc_%04d.exr").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const auto sharp = test::export_sharp(c, "sharp");
    r = test::cli("export '" + c.project.string() + "' --what confidence --format exr32 --out '" +
                  (c.dir / "conf").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const auto conf = read_all_frames((c.dir / "conf/confidence_%04d.exr").string());
    const auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((c.clip / "input_%04d.png").string());
    const auto invdepth = read_all_frames((c.clip / "invdepth_%04d.exr").string());
    const auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    REQUIRE(static_cast<int>(sharp.size()) == T);
    REQUIRE(static_cast<int>(conf.size()) == T);
    double in = 0, out = 0, in_p = 0, out_p = 0, in_w = 0, out_w = 0, k_p = 0, k_w = 0;
    double worst = 1e9;
    for (int t = 0; t < T; ++t) {
        const Regions g = regions(invdepth[t], alpha[t], 6);
        const double i = psnr(input[t], gt[t]), o = psnr(sharp[t], gt[t]);
        in += i / T, out += o / T, worst = std::min(worst, o - i);
        in_p += masked_psnr(input[t], gt[t], g.pillar, MaskRegion::Inside) / T;
        out_p += masked_psnr(sharp[t], gt[t], g.pillar, MaskRegion::Inside) / T;
        in_w += masked_psnr(input[t], gt[t], g.wall, MaskRegion::Inside) / T;
        out_w += masked_psnr(sharp[t], gt[t], g.wall, MaskRegion::Inside) / T;
        k_p += masked_mean(conf[t], g.pillar) / T;
        k_w += masked_mean(conf[t], g.wall) / T;
    }
    MESSAGE("whole frame: input " << in << " dB, output " << out << " dB, worst frame " << worst
                                  << " dB");
    MESSAGE("pillar: input " << in_p << " dB, output " << out_p << " dB, confidence " << k_p);
    MESSAGE("wall away from it: input " << in_w << " dB, output " << out_w << " dB, confidence "
                                        << k_w);
    CHECK(out > in + 1.0);      // the fit beats its input
    CHECK(worst > -0.5);        // and no frame is worse than the shot
    CHECK(out_p > in_p - 0.5);  // not even on the pillar the atlas cannot follow
    CHECK(k_p < k_w - 0.2);     // and the confidence pass says where the parallax is

    // The same fit at the defaults (the rule acts on the output only): still never worse.
    test::set_project_setting(c.project, "fit.sharper_view_px", std::nullopt);
    const auto plate = test::export_sharp(c, "sharp_default");
    double out_d = 0, worst_d = 1e9;
    for (int t = 0; t < T; ++t) {
        const double d = psnr(plate[t], gt[t]);
        out_d += d / T, worst_d = std::min(worst_d, d - psnr(input[t], gt[t]));
    }
    MESSAGE("defaults: output " << out_d << " dB, worst frame " << worst_d << " dB");
    CHECK(out_d >= in - 1e-3);
    CHECK(worst_d > -0.5);
}

namespace {

// The fit's own plate (every output rule off) with the true radius and masks (at this size the
// automatic masks are incoherent and the subject would join the wall's layer), plane + parallax
// on or off.
test::TinyClip fit_plate(const std::string& name, const std::string& scene, bool parallax,
                         int iters, std::string* log = nullptr) {
    test::TinyClip c = test::make_tiny(name, scene, scene == "pillar" ? "160x90" : "64x36");
    auto r = test::run(std::string("REFOCUS_THREADS=1 '") + REFOCUS_CLI + "' fit '" +
                       c.project.string() + "' --iters " + std::to_string(iters) +
                       " --set fit.fallback_k=0 --set fit.trust_seen_px=0 --set "
                       "fit.sharper_view_px=0 --set fit.keep_focus_px=0 --set fast.parallax=" +
                       (parallax ? "1" : "0") + " --coc '" + (c.clip / "coc_%04d.exr").string() +
                       "' --mask '" + (c.clip / "alpha_%04d.png").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    if (log) *log = r.output;
    return c;
}

}  // namespace

namespace {

// PSNR of the fit's plate and of the input on the pillar and on the wall away from it.
struct PillarScore {
    double in_p = 0, out_p = 0, in_w = 0, out_w = 0;
};

PillarScore score_pillar(const test::TinyClip& c, const std::vector<Image>& sharp) {
    const auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((c.clip / "input_%04d.png").string());
    const auto invdepth = read_all_frames((c.clip / "invdepth_%04d.exr").string());
    const auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    const int T = int(sharp.size());
    REQUIRE(T == int(gt.size()));
    PillarScore s;
    for (int t = 0; t < T; ++t) {
        const Regions g = regions(invdepth[t], alpha[t], 6);
        s.in_p += masked_psnr(input[t], gt[t], g.pillar, MaskRegion::Inside) / T;
        s.out_p += masked_psnr(sharp[t], gt[t], g.pillar, MaskRegion::Inside) / T;
        s.in_w += masked_psnr(input[t], gt[t], g.wall, MaskRegion::Inside) / T;
        s.out_w += masked_psnr(sharp[t], gt[t], g.wall, MaskRegion::Inside) / T;
    }
    return s;
}

}  // namespace

TEST_CASE("plane + parallax: the plate beats the wall's input and γ sets the pillar before it") {
    std::string log;
    const test::TinyClip c = fit_plate("plane_parallax_pillar", "pillar", true, 120, &log);
    // The pillar's depth is every frame pair's: the field is kept (fast.parallax_evidence).
    CHECK(log.find("half the pairs predict the other half") != std::string::npos);
    const test::TinyClip off = fit_plate("plane_parallax_pillar_off", "pillar", false, 120);
    const PillarScore on_s = score_pillar(c, test::export_sharp(c, "sharp"));
    const PillarScore off_s = score_pillar(off, test::export_sharp(off, "sharp"));
    auto r = test::cli("export '" + c.project.string() + "' --what parallax --out '" +
                       (c.dir / "parallax").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = test::cli("export '" + c.project.string() + "' --what uv --out '" +
                  (c.dir / "uv").string() + "'");
    REQUIRE(r.code == 0);
    const Image gamma = read_image_file((c.dir / "parallax/parallax_bg.exr").string()).image;
    const auto uv = read_all_frames((c.dir / "uv/uv_%04d.exr").string());
    const auto invdepth = read_all_frames((c.clip / "invdepth_%04d.exr").string());
    const auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    // γ where frame 0 sees the pillar and the wall (its uv in [-1, 1] over the atlas).
    const Regions g0 = regions(invdepth[0], alpha[0], 6);
    const int W = uv[0].width, H = uv[0].height;
    double gp = 0, np = 0, gw = 0, nw = 0;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const float* u = &uv[0].pixels[(y * W + x) * uv[0].channels];
            const int ax = std::clamp(int((u[0] + 1) * 0.5 * gamma.width), 0, gamma.width - 1);
            const int ay = std::clamp(int((u[1] + 1) * 0.5 * gamma.height), 0, gamma.height - 1);
            const double v = gamma.pixels[(ay * gamma.width + ax) * gamma.channels];
            if (g0.pillar.pixels[y * W + x] > 0.5f) gp += v, np += 1;
            if (g0.wall.pixels[y * W + x] > 0.5f) gw += v, nw += 1;
        }
    REQUIRE(np > 0);
    REQUIRE(nw > 0);
    gp /= np, gw /= nw;
    MESSAGE("plane + parallax on / off: pillar "
            << on_s.out_p << " / " << off_s.out_p << " dB (input " << on_s.in_p << "), wall "
            << on_s.out_w << " / " << off_s.out_w << " dB (input " << on_s.in_w
            << "); gamma pillar " << gp << ", wall " << gw);
    // The plate beats its input on the wall, and the pillar is nearer its input than without
    // the parallax field. At this size the field's 8 px cells carry the pillar's parallax onto
    // the wall beside it, which costs the wall against the per-frame warps alone (docs/method.md,
    // Model: plane + parallax); at 320x180 the wall gains.
    CHECK(on_s.out_w > on_s.in_w);
    CHECK(on_s.out_p > off_s.out_p);
    // The pillar stands off the wall's plane: its parallax is the larger.
    CHECK(std::abs(gp) > std::abs(gw) + 0.5);
}

TEST_CASE("plane + parallax: a static camera's fit is bit-identical with it on or off") {
    const test::TinyClip on = fit_plate("plane_parallax_static_on", "tripod", true, 12);
    const test::TinyClip off = fit_plate("plane_parallax_static_off", "tripod", false, 12);
    const auto a = test::export_sharp(on, "sharp"), b = test::export_sharp(off, "sharp");
    REQUIRE(a.size() == b.size());
    for (size_t t = 0; t < a.size(); ++t) CHECK(test::max_abs_diff(a[t], b[t]) == 0.0);
    // And it has no parallax field to export.
    auto r = test::cli("export '" + on.project.string() + "' --what parallax --out '" +
                       (on.dir / "px").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("no parallax field") != std::string::npos);
}
