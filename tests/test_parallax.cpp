// Parallax within a layer (synth scene "pillar"): a pillar stands in front of the wall, both in
// the background layer, and the camera trucks past them. No homography carries the layer from
// frame to frame, so the shared atlas cannot explain the pillar in every frame: the fit must
// still beat the shot, never be worse than it on the pillar, and say where it is unsure.
#include <torch/torch.h>

#include <doctest/doctest.h>

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
