// Parallax within a layer: residual warps from the optical flow (fit/flow_warp.h) and the fused
// atlas pulled back through them (model/atlas_geometry.h).
#include <torch/torch.h>

#include <doctest/doctest.h>

#include <cmath>

#include "fit/flow_warp.h"
#include "model/atlas_geometry.h"

using namespace refocus;

namespace {

// A clip whose camera moves by homographies that see the wall exactly, with a band of the layer
// (a pillar in front of it) sliding `slide` px a frame against the wall.
struct Parallax {
    int64_t T = 8, H = 48, W = 64;
    int64_t x0 = 24, x1 = 36;  // the band's columns in frame 0
    double slide = 1.0;
    torch::Tensor to_atlas, flow, valid;
    Parallax() {
        std::vector<torch::Tensor> hs;
        for (int64_t t = 0; t < T; ++t) hs.push_back(translation(2.0 * double(t), 0.0));
        to_atlas = torch::stack(hs).to(torch::kFloat32);
        // frame t sees the wall 2t px to the left of frame 0; the band moves with the camera
        // plus `slide`: flow is −2 on the wall and −2 + slide on the band.
        flow = torch::zeros({T - 1, 2, H, W});
        flow.select(1, 0).fill_(-2.0);
        for (int64_t t = 0; t + 1 < T; ++t) {
            const int64_t a = x0 - 2 * t + int64_t(slide * double(t));
            flow[t][0].narrow(1, a, x1 - x0).fill_(-2.0 + slide);
        }
        valid = torch::ones({T - 1, 1, H, W});
    }
};

}  // namespace

TEST_CASE("warps from the flow take up parallax that no homography carries") {
    Parallax c;
    const auto r = warps_from_flow(
        c.to_atlas, 1.0, c.flow, c.valid,
        [&](int64_t) {
            return torch::ones({1, c.H, c.W});
        },
        c.H / 4 + 2, c.W / 4 + 2);
    CHECK(r.points > 1000);
    // The band is 12 of 64 columns, wrong by `slide` px a pair through the homographies.
    CHECK(r.before_px == doctest::Approx(12.0 / 64.0).epsilon(0.15));
    CHECK(r.after_px < 0.35 * r.before_px);
    CHECK(r.warp.sizes() == torch::IntArrayRef({c.T, 2, c.H / 4 + 2, c.W / 4 + 2}));
    // The band's warp moves against the wall's by about `slide` px a frame over the clip,
    // read at the band's centre in each frame (grid nodes every (W − 1)/(gw − 1) px).
    auto w = r.warp.select(1, 0);  // [T,gh,gw], x
    const double spacing = double(c.W - 1) / double(c.W / 4 + 1);
    auto node = [&](int64_t t) {
        const double centre = 0.5 * double(c.x0 + c.x1) + (c.slide - 2.0) * double(t);
        return int64_t(std::lround(centre / spacing));
    };
    const int64_t gy = (c.H / 2) / 4, wall = 1;
    const double first = (w[0][gy][node(0)] - w[0][gy][wall]).item<double>();
    const double last = (w[c.T - 1][gy][node(c.T - 1)] - w[c.T - 1][gy][wall]).item<double>();
    CHECK(std::abs(last - first) > 0.4 * double(c.T - 1) * c.slide);
}

TEST_CASE("with the flow the homographies explain, the warps stay near zero") {
    Parallax c;
    c.flow.select(1, 0).fill_(-2.0);
    const auto r = warps_from_flow(
        c.to_atlas, 1.0, c.flow, c.valid,
        [&](int64_t) {
            return torch::ones({1, c.H, c.W});
        },
        c.H / 4 + 2, c.W / 4 + 2);
    CHECK(r.before_px < 1e-4);
    CHECK(r.warp.abs().max().item<double>() < 0.05);
}

TEST_CASE("points outside the layer or with an inconsistent flow are not used") {
    Parallax c;
    auto region = [&](int64_t) {
        auto m = torch::ones({1, c.H, c.W});
        m.narrow(2, 0, c.W / 2).zero_();
        return m;
    };
    c.valid.narrow(2, 0, c.H / 2).zero_();
    const auto all = warps_from_flow(
        c.to_atlas, 1.0, c.flow, torch::ones_like(c.valid),
        [&](int64_t) {
            return torch::ones({1, c.H, c.W});
        },
        14, 18, 10);
    const auto some = warps_from_flow(c.to_atlas, 1.0, c.flow, c.valid, region, 14, 18, 10);
    CHECK(some.points > 0);
    CHECK(some.points < all.points / 3);
}

TEST_CASE("a constant offset pulls the fused atlas back as a translation does") {
    const int64_t T = 3, H = 20, W = 24;
    auto src = torch::rand({T, 3, H, W});
    auto weight = torch::ones({T, 1, H, W});
    auto h = torch::eye(3).expand({T, 3, 3}).contiguous();
    // offset (+3, −2) atlas px at every frame pixel: the same mapping as translation(3, −2)
    auto moved = torch::stack({translation(3, -2), translation(3, -2), translation(3, -2)})
                     .to(torch::kFloat32);
    auto a = fuse_frames(moved, 30, 34, src, weight);
    auto off = torch::stack({torch::full({H, W}, 3.0f), torch::full({H, W}, -2.0f)});
    auto b = fuse_frames(
        h, 30, 34, [&](int64_t t) { return src[t]; }, [&](int64_t t) { return weight[t]; },
        [&](int64_t) { return off; });
    CHECK((a - b).abs().max().item<double>() < 1e-4);
}

namespace {

// Plane + parallax from the flow on the sliding band, scored on the pairs it was not fitted to.
ParallaxInit parallax_of(const Parallax& c, bool correct_homographies = false) {
    const int64_t T = c.T;
    auto epipole = torch::zeros({T, 3}), centre = torch::zeros({T, 2});
    for (int64_t t = 0; t < T; ++t) {
        epipole[t][0] = 2.0 * double(t) / (2.0 * double(T - 1));  // lateral travel over its largest
        centre[t][0] = 0.5 * double(c.W - 1) + 2.0 * double(t);
        centre[t][1] = 0.5 * double(c.H - 1);
    }
    const double radius = 0.5 * std::hypot(double(c.W), double(c.H));
    const int64_t aw = c.W + 2 * (T - 1), ah = c.H;
    return parallax_from_flow(
        c.to_atlas, c.flow, c.valid,
        [&](int64_t) {
            return torch::ones({1, c.H, c.W});
        },
        epipole, centre, radius, aw, ah, ah / 4 + 2, aw / 4 + 2, 0.0, 150, 4, correct_homographies);
}

// Mean distance (atlas px) between where `to_atlas` and the true homographies send the pixels.
double mapping_error(const torch::Tensor& to_atlas, const torch::Tensor& truth, int64_t H,
                     int64_t W) {
    auto g = torch::meshgrid({torch::arange(H, torch::kFloat64), torch::arange(W, torch::kFloat64)},
                             "ij");
    auto p = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({H * W}, torch::kFloat64)});
    auto a = torch::matmul(to_atlas.to(torch::kFloat64), p), b = torch::matmul(truth, p);
    auto d = a.narrow(1, 0, 2) / a.narrow(1, 2, 1) - b.narrow(1, 0, 2) / b.narrow(1, 2, 1);
    return d.norm(2, 1).mean().item<double>();
}

}  // namespace

TEST_CASE("plane + parallax: a depth every frame pair shares is predicted on the pairs held out") {
    const ParallaxInit r = parallax_of(Parallax());
    REQUIRE(std::isfinite(r.held_before_px));
    MESSAGE("held out " << r.held_before_px << " -> " << r.held_after_px << " px");
    CHECK(r.after_px < 0.5 * r.before_px);
    CHECK(r.held_after_px < 0.6 * r.held_before_px);
}

TEST_CASE("plane + parallax: the flow's own errors, differing pair by pair, predict nothing") {
    // The wall alone, its flow wrong by 0.3 px (σ) independently in every pair and pixel block:
    // a field fitted to the even pairs fits their errors, and the odd pairs gain nothing from it.
    Parallax c;
    c.flow.select(1, 0).fill_(-2.0);
    torch::manual_seed(7);
    auto err = torch::randn({c.T - 1, 2, c.H / 4, c.W / 4}) * 0.3;
    c.flow +=
        torch::nn::functional::interpolate(err, torch::nn::functional::InterpolateFuncOptions()
                                                    .size(std::vector<int64_t>{c.H, c.W})
                                                    .mode(torch::kNearest));
    const ParallaxInit r = parallax_of(c);
    REQUIRE(std::isfinite(r.held_before_px));
    MESSAGE("held out " << r.held_before_px << " -> " << r.held_after_px << " px");
    CHECK(r.held_after_px > 0.98 * r.held_before_px);  // under the 2 % fast.parallax_evidence needs
}

TEST_CASE("plane + parallax: fewer than two frame pairs of each parity are not scored") {
    Parallax d;  // three pairs of flow: one of them odd
    d.to_atlas = d.to_atlas.narrow(0, 0, 4);
    d.flow = d.flow.narrow(0, 0, 3);
    d.valid = d.valid.narrow(0, 0, 3);
    d.T = 4;
    const ParallaxInit r = parallax_of(d);
    CHECK(r.points > 0);
    CHECK(std::isnan(r.held_before_px));
    CHECK(std::isnan(r.held_after_px));
}

TEST_CASE("plane + parallax: homographies that drift are corrected with the field") {
    // Each frame's homography wrong by a zoom growing 0.5 % a frame and a vertical shift of its
    // own, as pairwise homographies chained over a clip drift; the flow is the scene's.
    Parallax c;
    const auto truth = c.to_atlas.to(torch::kFloat64);
    auto wrong = truth.clone();
    const double dy[] = {0, 0.4, -0.3, 0.5, 0.9, 0.2, 1.1, 0.6};
    for (int64_t t = 1; t < c.T; ++t) {
        auto err = torch::eye(3, torch::kFloat64);
        err[0][0] = err[1][1] = 1.0 + 0.005 * double(t);
        err[1][2] = dy[t];
        wrong[t] = torch::matmul(err, truth[t]);
    }
    c.to_atlas = wrong.to(torch::kFloat32);
    const ParallaxInit plain = parallax_of(c), corrected = parallax_of(c, true);
    CHECK(!plain.correction.defined());
    REQUIRE(corrected.correction.defined());
    CHECK(corrected.correction[0].allclose(torch::eye(3, torch::kFloat64)));  // frame 0 holds
    const double before = mapping_error(wrong, truth, c.H, c.W);
    const double after = mapping_error(torch::matmul(corrected.correction, wrong), truth, c.H, c.W);
    MESSAGE("disagreement " << plain.after_px << " -> " << corrected.after_px
                            << " px; mapping error " << before << " -> " << after << " px");
    CHECK(corrected.after_px < 0.5 * plain.after_px);
    CHECK(after < 0.5 * before);
}
