// Metrics against values worked out by hand.
#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "metrics/metrics.h"
#include "util/error.h"

using namespace refocus;

namespace {
// A linear image whose sRGB 8-bit encoding is exactly `code` everywhere.
Image code_image(int w, int h, int code) {
    return Image(w, h, 3, srgb8_to_linear_table()[code]);
}
}  // namespace

TEST_CASE("PSNR by hand") {
    // One value of 48 off by the full range: MSE = 255²/48, PSNR = 10·log10(48) = 16.8124 dB.
    Image a(4, 4, 3, 0.0f), b = a;
    b.pixels[7] = 1.0f;
    CHECK(psnr(a, b) == doctest::Approx(10 * std::log10(48.0)).epsilon(1e-9));
    // Every value off by 5 code levels: PSNR = 20·log10(255/5) = 34.1514 dB.
    CHECK(psnr(code_image(8, 8, 100), code_image(8, 8, 105)) ==
          doctest::Approx(20 * std::log10(255.0 / 5)).epsilon(1e-9));
    // Identical images: capped at 100 dB.
    CHECK(psnr(a, a) == 100.0);
    // Shape mismatch is an error, not a number.
    CHECK_THROWS_AS(psnr(a, Image(4, 5, 3)), Error);
}

TEST_CASE("SSIM and MS-SSIM identities") {
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    Image x(200, 180, 3);
    for (float& v : x.pixels) v = u(rng);
    CHECK(ssim(x, x) == doctest::Approx(1.0).epsilon(1e-12));
    int scales = 0;
    CHECK(ms_ssim_raw(to_metric_space(x), to_metric_space(x), 255, &scales) ==
          doctest::Approx(1.0).epsilon(1e-12));
    CHECK(scales == 5);
    // Too small for 5 scales: 64 px → 3 scales (64, 32, 16 ≥ 11).
    Image small(64, 64, 3, 0.2f);
    ms_ssim_raw(to_metric_space(small), to_metric_space(small), 255, &scales);
    CHECK(scales == 3);
}

TEST_CASE("SSIM of flat images: only the luminance term, by hand") {
    // μa = 100, μb = 110, no variance: SSIM = (2·100·110 + C1) / (100² + 110² + C1),
    // C1 = (0.01·255)² = 6.5025 → 0.995476.
    Image a(32, 32, 3, 100.0f), b(32, 32, 3, 110.0f);
    const double c1 = 6.5025;
    const double expect = (2 * 100 * 110 + c1) / (100 * 100 + 110 * 110 + c1);
    CHECK(ssim_raw(a, b, 255) == doctest::Approx(expect).epsilon(1e-9));
    // MS-SSIM: every contrast-structure term is 1 (no variance), the coarsest scale keeps the
    // luminance term with exponent 0.1333 / Σw (Σw = 1.0001).
    Image a2(192, 192, 3, 100.0f), b2(192, 192, 3, 110.0f);
    CHECK(ms_ssim_raw(a2, b2, 255) ==
          doctest::Approx(std::pow(expect, 0.1333 / 1.0001)).epsilon(1e-9));
}

TEST_CASE("SSIM of a noisy copy follows the reference formula") {
    // x uniform in [0,255] (σx² = 255²/12), y = x + n with independent Gaussian noise σn.
    // Means agree (l ≈ 1), so SSIM ≈ (2σx² + C2) / (2σx² + σn² + C2), C2 = (0.03·255)².
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(0.0f, 255.0f);
    std::normal_distribution<float> n(0.0f, 20.0f);
    Image x(256, 256, 1), y(256, 256, 1);
    for (size_t i = 0; i < x.size(); ++i) {
        x.pixels[i] = u(rng);
        y.pixels[i] = x.pixels[i] + n(rng);
    }
    const double sx2 = 255.0 * 255.0 / 12, sn2 = 400.0, c2 = std::pow(0.03 * 255, 2);
    const double expect = (2 * sx2 + c2) / (2 * sx2 + sn2 + c2);
    CHECK(ssim_raw(x, y, 255) == doctest::Approx(expect).epsilon(0.01));
}

TEST_CASE("tPSNR by hand") {
    std::vector<Image> gt, same_offset, flicker;
    for (int t = 0; t < 4; ++t) {
        gt.push_back(code_image(16, 16, 100 + 10 * t));
        same_offset.push_back(code_image(16, 16, 103 + 10 * t));                 // constant bias
        flicker.push_back(code_image(16, 16, 100 + 10 * t + (t % 2 ? 3 : -3)));  // ±3 alternation
    }
    // A constant bias does not flicker: consecutive differences match exactly.
    CHECK(tpsnr(same_offset, gt) == 100.0);
    // ±3 alternation: every difference is off by 6 → tPSNR = 20·log10(255/6) = 32.568 dB.
    CHECK(tpsnr(flicker, gt) == doctest::Approx(20 * std::log10(255.0 / 6)).epsilon(1e-9));
    // ... while its per-frame PSNR is 20·log10(255/3).
    CHECK(mean_psnr(flicker, gt) == doctest::Approx(20 * std::log10(255.0 / 3)).epsilon(1e-9));
    CHECK_THROWS_AS(tpsnr({gt[0]}, {gt[0]}), Error);
}

TEST_CASE("masked PSNR by hand: inside and outside the mask") {
    // The left half (x < 4 of 8) is off by 5 code levels, the right half by 10; the mask covers
    // the left half (values 0.5 and 1: both inside; 0.49: outside).
    Image gt = code_image(8, 4, 100), pred = gt, mask(8, 4, 1, 0.0f);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 8; ++x) {
            const int code = x < 4 ? 105 : 110;
            for (int c = 0; c < 3; ++c) pred.at(x, y, c) = srgb8_to_linear_table()[code];
            mask.at(x, y, 0) = x < 4 ? (x % 2 ? 0.5f : 1.0f) : 0.49f;
        }
    CHECK(masked_psnr(pred, gt, mask, MaskRegion::Inside) ==
          doctest::Approx(20 * std::log10(255.0 / 5)).epsilon(1e-9));
    CHECK(masked_psnr(pred, gt, mask, MaskRegion::Outside) ==
          doctest::Approx(20 * std::log10(255.0 / 10)).epsilon(1e-9));
    // The whole frame: MSE (25 + 100) / 2.
    CHECK(psnr(pred, gt) == doctest::Approx(10 * std::log10(255.0 * 255 / 62.5)).epsilon(1e-9));
    // An all-inside mask gives the plain PSNR; the empty region gives NaN.
    Image all(8, 4, 1, 1.0f);
    CHECK(masked_psnr(pred, gt, all, MaskRegion::Inside) == doctest::Approx(psnr(pred, gt)));
    CHECK(std::isnan(masked_psnr(pred, gt, all, MaskRegion::Outside)));
    // A 4-channel mask is read from its first channel; a mask of another size is an error.
    Image rgba(8, 4, 4, 0.0f);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) rgba.at(x, y, 0) = 1.0f;
    CHECK(masked_psnr(pred, gt, rgba, MaskRegion::Inside) ==
          doctest::Approx(20 * std::log10(255.0 / 5)).epsilon(1e-9));
    CHECK_THROWS_AS(masked_psnr(pred, gt, Image(4, 4, 1, 1.0f), MaskRegion::Inside), Error);
}

TEST_CASE("error by spatial frequency band") {
    // A random image and two predictions of it, in linear metric space (no rounding): the image
    // itself, and its contrast halved about its mean. Both are linear in the DFT, so the gain
    // is exactly 1 and 0.5 in every band, and the halved one's error is a quarter of the truth's
    // power band by band.
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Image> gt(2, Image(48, 32, 3)), same, half;
    for (auto& g : gt)
        for (float& v : g.pixels) v = u(rng);
    for (const auto& g : gt) {
        same.push_back(g);
        Image h = g;
        for (int c = 0; c < 3; ++c) {
            double m = 0;
            for (int y = 0; y < g.height; ++y)
                for (int x = 0; x < g.width; ++x) m += g.at(x, y, c);
            m /= double(g.width) * g.height;
            for (int y = 0; y < g.height; ++y)
                for (int x = 0; x < g.width; ++x)
                    h.at(x, y, c) = float(m + 0.5 * (g.at(x, y, c) - m));
        }
        half.push_back(h);
    }
    const std::vector<double> edges{0, 0.1, 0.25, 0.5, 0.71};
    const auto s = error_by_band(same, gt, edges, MetricSpace::Linear);
    const auto h = error_by_band(half, gt, edges, MetricSpace::Linear);
    REQUIRE(s.size() == 4);
    double share = 0;
    for (size_t i = 0; i < h.size(); ++i) {
        CHECK(h[i].lo == edges[i]);
        CHECK(h[i].hi == edges[i + 1]);
        CHECK(h[i].gt_power > 0);
        CHECK(s[i].err_power == doctest::Approx(0.0).epsilon(1e-12));
        CHECK(s[i].gain == doctest::Approx(1.0).epsilon(1e-6));
        CHECK(h[i].gain == doctest::Approx(0.5).epsilon(1e-4));
        CHECK(h[i].err_power == doctest::Approx(0.25 * h[i].gt_power).epsilon(1e-3));
        share += h[i].err_share;
    }
    CHECK(share == doctest::Approx(1.0).epsilon(1e-9));

    // A 3x3 box blur keeps the low band and loses the high ones: gain falls with frequency.
    std::vector<Image> blur;
    for (const auto& g : gt) {
        Image b = g;
        for (int y = 1; y + 1 < g.height; ++y)
            for (int x = 1; x + 1 < g.width; ++x)
                for (int c = 0; c < 3; ++c) {
                    float a = 0;
                    for (int dy = -1; dy <= 1; ++dy)
                        for (int dx = -1; dx <= 1; ++dx) a += g.at(x + dx, y + dy, c);
                    b.at(x, y, c) = a / 9;
                }
        blur.push_back(b);
    }
    const auto b = error_by_band(blur, gt, edges, MetricSpace::Linear);
    CHECK(b[0].gain > 0.7);
    CHECK(b[0].gain > b[1].gain);
    CHECK(b[1].gain > b[2].gain);
    CHECK(b[2].err_share > b[0].err_share);

    // Bad input is an error naming the problem.
    CHECK_THROWS_AS(error_by_band(same, std::vector<Image>(1, gt[0]), edges), Error);
    CHECK_THROWS_AS(error_by_band(same, gt, {0.1, 0.5}), Error);
    CHECK_THROWS_AS(error_by_band(same, gt, {0, 0.5, 0.2}), Error);
    CHECK_THROWS_AS(error_by_band({Image(8, 8, 3)}, {Image(8, 9, 3)}, edges), Error);
}
