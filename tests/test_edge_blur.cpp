// Absolute blur at edges (radius/edge_blur.h): a step blurred by the fit's own kernel reads its
// radius at any orientation and sub-pixel position, a sharp step reads 0, and texture that is
// not an isolated step is not taken for one.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <cmath>

#include "radius/edge_blur.h"
#include "util/error.h"

using namespace refocus;

namespace {

LensBlurParams pillbox() {
    LensBlurParams p;
    p.kernel = BlurKernel::Pillbox;
    return p;
}

// A straight step through (cx, cy) with normal angle `deg`, pixel-integrated (4x4 supersampled),
// from `lo` to `hi`, blurred by the pillbox of radius r.
torch::Tensor blurred_step(int H, int W, double cx, double cy, double deg, double r,
                           float lo = 0.1f, float hi = 0.6f) {
    const double a = deg * M_PI / 180, nx = std::cos(a), ny = std::sin(a);
    auto img = torch::zeros({1, H, W});
    auto acc = img.accessor<float, 3>();
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            int in = 0;
            for (int j = 0; j < 4; ++j)
                for (int i = 0; i < 4; ++i)
                    in += ((x - 0.375 + 0.25 * i - cx) * nx + (y - 0.375 + 0.25 * j - cy) * ny) > 0;
            acc[0][y][x] = lo + (hi - lo) * in / 16.0f;
        }
    return lens_blur(img, torch::full({H, W}, float(r)), pillbox())[0];
}

double median_of(const torch::Tensor& v) {
    return v.median().item<double>();
}

}  // namespace

TEST_CASE(
    "edge blur: a step blurred by the fit's pillbox reads its radius, at any angle and offset") {
    const int H = 96, W = 96;
    auto allowed = torch::ones({H, W}, torch::kBool);
    for (double r : {0.0, 1.5, 3.0, 6.0}) {
        for (double deg : {0.0, 30.0, 90.0, 135.0}) {
            auto img = blurred_step(H, W, 47.3, 48.6, deg, r);
            EdgeBlurSamples e = measure_edge_blur(img, allowed, pillbox());
            INFO("r " << r << " angle " << deg << ": " << e.size() << " edges of " << e.candidates);
            REQUIRE(e.size() >= 10);
            const double m = median_of(e.radius);
            MESSAGE("step r=" << r << " at " << deg << " deg reads " << m << " px (" << e.size()
                              << " edges)");
            const bool axis = deg == 0.0 || deg == 90.0;
            if (r == 0.0 && !axis)  // a pixel seen along its diagonal spans √2 px: a sharp
                CHECK(m <= 0.75);   // oblique step reads 0.75, under the floor's dead zone
            else
                CHECK(std::abs(m - r) <= (axis ? 0.3 : 0.6));
        }
    }
}

TEST_CASE(
    "edge blur: profiles stay inside the allowed region; weak steps and flat images give nothing") {
    const int H = 80, W = 80;
    auto img = blurred_step(H, W, 40.2, 40.0, 0.0, 3.0);
    // The step's own column is allowed, but not the side of it the fit window needs.
    auto allowed = torch::zeros({H, W}, torch::kBool);
    allowed.narrow(1, 36, 6).fill_(true);
    CHECK(measure_edge_blur(img, allowed, pillbox()).size() == 0);
    // A step of 1% contrast is under min_contrast.
    auto weak = blurred_step(H, W, 40.2, 40.0, 0.0, 3.0, 0.50f, 0.51f);
    CHECK(measure_edge_blur(weak, torch::ones({H, W}, torch::kBool), pillbox()).size() == 0);
    CHECK(measure_edge_blur(torch::full({H, W}, 0.3f), torch::ones({H, W}, torch::kBool), pillbox())
              .size() == 0);
    CHECK_THROWS_AS(measure_edge_blur(img, torch::ones({H, W + 1}, torch::kBool), pillbox()),
                    Error);
}

TEST_CASE("edge blur: fine texture is not read as a blurred step") {
    // Sharp white noise and sharp 3 px stripes: every gradient maximum has another within the fit
    // window, so few profiles look like one step, and those that pass read no large blur.
    const int H = 96, W = 96;
    torch::manual_seed(3);
    auto allowed = torch::ones({H, W}, torch::kBool);
    auto noise = torch::rand({H, W}) * 0.5 + 0.1;
    EdgeBlurSamples e = measure_edge_blur(noise, allowed, pillbox());
    MESSAGE("noise: " << e.size() << " of " << e.candidates << " edges accepted");
    CHECK(e.size() <= e.candidates / 20);
    if (e.size() > 0) CHECK(median_of(e.radius) < 1.0);
    auto x = torch::arange(W, torch::kFloat32).view({1, W}).expand({H, W});
    auto stripes = (torch::fmod(x, 6.0) < 3.0).to(torch::kFloat32) * 0.5 + 0.1;
    e = measure_edge_blur(stripes, allowed, pillbox());
    MESSAGE("stripes: " << e.size() << " of " << e.candidates << " edges accepted");
    if (e.size() > 0) CHECK(median_of(e.radius) < 1.0);
}

TEST_CASE("edge blur: the model's step responses are the lens blur layer's own") {
    EdgeBlurOptions o;
    std::vector<double> radii, offsets;
    auto M = edge_spread_table(pillbox(), o, &radii, &offsets);
    REQUIRE(M.size(0) == int64_t(radii.size() * offsets.size()));
    REQUIRE(M.size(1) == 2 * o.reach + 1);
    // Every response rises from 0 to 1, monotone, and is symmetric about its offset.
    CHECK(M.select(1, 0).abs().max().item<double>() < 1e-6);
    CHECK((M.select(1, M.size(1) - 1) - 1).abs().max().item<double>() < 1e-5);
    CHECK((M.narrow(1, 1, M.size(1) - 1) - M.narrow(1, 0, M.size(1) - 1)).min().item<double>() >
          -1e-6);
    // Offset 0 (the middle of `offsets`): value ½ at the step.
    const int64_t k0 = (offsets.size() / 2);
    for (size_t i = 0; i < radii.size(); i += 8)
        CHECK(M[i * offsets.size() + k0][o.reach].item<double>() ==
              doctest::Approx(0.5).epsilon(1e-4));
}
