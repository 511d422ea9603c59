// Absolute blur from tile spectra (radius/spectral_blur.h): textures blurred by the fit's own
// kernel at 5-10 px read their radius; tiles touching what is not allowed are not read; a radius
// at the end of the searched range gives no reading.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <cmath>
#include <cstdlib>
#include <iostream>

#include "radius/spectral_blur.h"
#include "util/error.h"

using namespace refocus;

namespace {

LensBlurParams pillbox() {
    LensBlurParams p;
    p.kernel = BlurKernel::Pillbox;
    return p;
}

// Natural-image-like texture: white noise shaped to a 1/|f| amplitude spectrum, in [0.05, 0.95].
torch::Tensor pink_texture(int H, int W, uint64_t seed) {
    torch::manual_seed(seed);
    auto n = torch::randn({H, W}, torch::kFloat64);
    auto fy = torch::fft::fftfreq(H, torch::kFloat64).view({H, 1});
    auto fx = torch::fft::fftfreq(W, torch::kFloat64).view({1, W});
    auto f = (fy * fy + fx * fx).sqrt().clamp_min(1.0 / std::max(H, W));
    auto x = torch::real(torch::fft::ifft2(torch::fft::fft2(n) / f));
    x = (x - x.min()) / (x.max() - x.min());
    return (0.05 + 0.9 * x).to(torch::kFloat32);
}

// Man-made texture: rectangles ("glyphs") of 2-12 px at random places and grey levels over
// stripes, the kind of wall the synth clips hold.
torch::Tensor glyph_texture(int H, int W, uint64_t seed) {
    std::srand(unsigned(seed));
    auto img = torch::full({H, W}, 0.4f);
    auto a = img.accessor<float, 2>();
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) a[y][x] = ((x / 5) % 2) ? 0.55f : 0.35f;
    for (int k = 0; k < H * W / 40; ++k) {
        const int w = 2 + std::rand() % 11, h = 2 + std::rand() % 11;
        const int x0 = std::rand() % W, y0 = std::rand() % H;
        const float v = 0.05f + 0.9f * float(std::rand() % 1000) / 1000.0f;
        for (int y = y0; y < std::min(H, y0 + h); ++y)
            for (int x = x0; x < std::min(W, x0 + w); ++x) a[y][x] = v;
    }
    return img;
}

// Blurred by the pillbox of radius r, quantised to 8 bits (the frames are 8-bit).
torch::Tensor blur8(const torch::Tensor& img, double r) {
    const int64_t H = img.size(0), W = img.size(1);
    auto b = lens_blur(img.unsqueeze(0), torch::full({H, W}, float(r)), pillbox())[0];
    return (b * 255).round() / 255;
}

}  // namespace

TEST_CASE("spectral blur: textures blurred by 5-10 px read their radius") {
    const int H = 180, W = 320;
    auto allowed = torch::ones({H, W}, torch::kBool);
    for (int kind = 0; kind < 2; ++kind) {
        auto tex = kind == 0 ? pink_texture(H, W, 3) : glyph_texture(H, W, 5);
        for (double r : {5.0, 7.0, 9.5}) {
            auto s = measure_spectral_blur(blur8(tex, r), allowed, pillbox());
            REQUIRE(s.size() >= 20);
            const double m = s.radius.median().item<double>();
            const double within =
                ((s.radius - r).abs() < 0.1 * r).to(torch::kFloat32).mean().item<double>();
            MESSAGE(std::string(kind == 0 ? "pink" : "glyphs")
                    << " r=" << r << ": median " << m << " px, " << s.size() << " of " << s.tiles
                    << " tiles, " << within * 100 << "% within 10%");
            CHECK(std::abs(m - r) < 0.05 * r);
            CHECK(within > 0.6);
        }
    }
}

TEST_CASE(
    "spectral blur: only tiles wholly inside `allowed` are read; out-of-range blur gives no "
    "reading") {
    const int H = 120, W = 320;
    auto tex = blur8(pink_texture(H, W, 7), 6.0);
    auto allowed = torch::ones({H, W}, torch::kBool);
    allowed.narrow(1, 150, 10).fill_(false);
    auto s = measure_spectral_blur(tex, allowed, pillbox());
    REQUIRE(s.tiles > 0);
    for (int64_t i = 0; i < s.size(); ++i) {
        const double x = s.x[i].item<double>();
        CHECK((x + 64 <= 150 ||
               x - 64 >= 160));  // tile_w 128: its half-width each side of the centre
    }
    // A sharp texture: the evidence keeps falling toward the lower end, so no tile reads.
    auto sharp = measure_spectral_blur(blur8(pink_texture(H, W, 7), 0.0),
                                       torch::ones({H, W}, torch::kBool), pillbox());
    MESSAGE("sharp texture: " << sharp.size() << " readings of " << sharp.tiles
                              << " tiles: " << sharp.radius);
    CHECK(sharp.size() == 0);
    // Nothing allowed: no tile.
    auto none = measure_spectral_blur(tex, torch::zeros({H, W}, torch::kBool), pillbox());
    CHECK(none.tiles == 0);
    CHECK(none.size() == 0);
}

TEST_CASE("spectral blur: a tile too small for the largest kernel is an error") {
    SpectralBlurOptions o;
    o.tile_h = 16;
    o.tile_w = 16;
    CHECK_THROWS_AS(
        measure_spectral_blur(torch::zeros({32, 32}), torch::ones({32, 32}), pillbox(), o), Error);
}

TEST_CASE(
    "spectral blur: a frame past max_width is read at a fraction of its size, readings scaled "
    "back") {
    // 960x540, blurred by 21 px: read at 1/2 size (10.5 px there), places and radii in full-size
    // px.
    const int H = 540, W = 960;
    auto tex = blur8(pink_texture(H, W, 11), 21.0);
    auto allowed = torch::ones({H, W}, torch::kBool);
    allowed.narrow(1, 0, 300).fill_(false);  // the left third not allowed
    auto s = measure_spectral_blur(tex, allowed, pillbox());
    REQUIRE(s.size() >= 20);
    const double m = s.radius.median().item<double>();
    MESSAGE("960x540 blurred by 21 px: median " << m << " px, " << s.size() << " of " << s.tiles
                                                << " tiles");
    CHECK(std::abs(m - 21.0) < 0.05 * 21.0);
    CHECK(s.tiles <= SpectralBlurOptions{}.max_tiles);
    CHECK(s.x.min().item<double>() - 128 >=
          300 - 1);  // a tile's half-width (64 px at 1/2 size) past the edge
    CHECK(s.x.max().item<double>() + 128 <= W);
}
