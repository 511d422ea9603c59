// The clip's noise estimate (prepare/noise.h): known noise added to clean synth frames, in 8-bit
// levels, read back within 0.3 levels or 20 %; texture and clipping do not count as noise.
#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "io/image.h"
#include "prepare/noise.h"
#include "synth/synth.h"

using namespace refocus;

namespace {

// A linear frame with Gaussian noise of `sigma` levels added in 8-bit sRGB and then rounded to
// 8 bits, as a camera file holds it.
Image noisy_8bit(const Image& linear, double sigma, uint32_t seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> n(0.0, sigma);
    Image out = linear;
    for (float& v : out.pixels) {
        const double s = 255.0 * linear_to_srgb(v) + (sigma > 0 ? n(rng) : 0.0);
        const double code = std::min(255.0, std::max(0.0, std::round(s)));
        v = srgb8_to_linear_table()[int(code)];
    }
    return out;
}

double within(double measured, double truth) {
    return std::max(0.3, 0.2 * truth) - std::abs(measured - truth);
}

}  // namespace

TEST_CASE("noise estimate: known noise on synth frames, 8-bit") {
    // tripod sweeps its focus over finely textured walls: its sharp frames alone read several
    // levels with no noise added.
    for (const char* scene : {"rack", "pan", "tripod"}) {
        SynthOptions o;
        o.scene = scene;
        o.frames = 12;
        SynthClip clip(o);
        std::vector<Image> frames;
        for (int t : noise_sample_frames(o.frames)) frames.push_back(clip.render(t).input);
        for (double sigma : {0.0, 0.5, 1.0, 2.0, 4.0}) {
            std::vector<std::array<double, 3>> per;
            for (size_t k = 0; k < frames.size(); ++k)
                per.push_back(frame_noise_levels(noisy_8bit(frames[k], sigma, 7 + uint32_t(k)),
                                                 source_rounding_var("uint8")));
            const NoiseEstimate e = combine_frame_noise(per);
            INFO(scene << " sigma " << sigma << ": " << e.describe());
            REQUIRE(e.measured());
            MESSAGE(scene << " sigma " << sigma << ": " << e.describe());
            for (int c = 0; c < 3; ++c) CHECK(within(e.sigma[c], sigma) >= 0);
        }
    }
}

TEST_CASE("noise estimate: edges and gradients are not noise, clipping is left out") {
    // Sharp-edged squares of 12 px on smooth ramps: every cell near an edge holds strong HH.
    Image edges(320, 180, 3);
    for (int y = 0; y < edges.height; ++y)
        for (int x = 0; x < edges.width; ++x)
            for (int c = 0; c < 3; ++c) {
                const bool on = ((x / 12) + (y / 12) + c) % 2 == 0;
                const double ramp = 0.25 * x / edges.width + 0.15 * y / edges.height;
                edges.at(x, y, c) = float(srgb_to_linear(float((on ? 0.6 : 0.2) + ramp)));
            }
    for (double sigma : {0.0, 2.0}) {
        const auto s =
            frame_noise_levels(noisy_8bit(edges, sigma, 1), source_rounding_var("uint8"));
        for (int c = 0; c < 3; ++c) CHECK(within(s[c], sigma) >= 0);
    }
    // Half the frame clipped to white: the rest still gives the noise.
    SynthOptions o;
    o.scene = "tripod";
    SynthClip clip(o);
    Image half = clip.render(0).input;
    for (int y = 0; y < half.height / 2; ++y)
        for (int x = 0; x < half.width; ++x)
            for (int c = 0; c < 3; ++c) half.at(x, y, c) = 4.0f;
    const auto h = frame_noise_levels(noisy_8bit(half, 2.0, 3), source_rounding_var("uint8"));
    for (int c = 0; c < 3; ++c) CHECK(within(h[c], 2.0) >= 0);
}

TEST_CASE("noise estimate: stored in the project, refused when malformed") {
    NoiseEstimate e;
    e.sigma = {{1.5, 1.25, 2.0}};
    e.frames = 9;
    const NoiseEstimate back = NoiseEstimate::from_json(e.to_json(), "p/project.json");
    CHECK(back.sigma[2] == doctest::Approx(2.0));
    CHECK(back.frames == 9);
    CHECK_THROWS_WITH(
        NoiseEstimate::from_json({{"sigma_levels", {1, 2}}, {"frames", 3}}, "p/project.json"),
        doctest::Contains("p/project.json"));
    CHECK_THROWS(NoiseEstimate::from_json({{"sigma_levels", {1, -2, 3}}, {"frames", 3}}, "x"));
    CHECK_THROWS(NoiseEstimate::from_json({{"sigma_levels", {1, 2, 3}}}, "x"));
    CHECK(NoiseEstimate{}.describe() == "not measured");
    CHECK(noise_sample_frames(30).size() == 9);
    CHECK(noise_sample_frames(3).size() == 3);
    CHECK(noise_sample_frames(30).back() == 29);
}
