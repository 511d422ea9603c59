// The fit's losses: the fused MS-SSIM against its reference, weighted TV and TV by radius.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <array>
#include <cmath>

#include "fit/losses.h"
#include "util/error.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE(
    "MS-SSIM loss: the fused Gaussian filter matches the tensor-op reference, value and gradient") {
    torch::manual_seed(7);
    SUBCASE(
        "the filter: an impulse gives the 11x11 window, a constant stays, the adjoint is exact") {
        auto x = torch::zeros({1, 1, 21, 23}, torch::kDouble);
        x[0][0][10][11] = 1.0;
        auto y = gauss_filter_valid(x);
        REQUIRE(y.sizes() == torch::IntArrayRef({1, 1, 11, 13}));
        CHECK(y.sum().item<double>() == doctest::Approx(1.0).epsilon(1e-12));
        CHECK(torch::allclose(y, gauss_filter_valid_reference(x), 0, 1e-15));
        const double g5 = y[0][0][5][6].item<double>(), g0 = y[0][0][0][1].item<double>();
        CHECK(g5 > 0.07);  // the centre tap squared: (1 / Σ exp(−i²/4.5))²
        CHECK(g0 ==
              doctest::Approx(g5 * std::exp(-25.0 / 4.5) * std::exp(-25.0 / 4.5)).epsilon(1e-9));
        auto c = torch::full({2, 3, 15, 17}, 0.25, torch::kDouble);
        CHECK(torch::allclose(gauss_filter_valid(c),
                              torch::full({2, 3, 5, 7}, 0.25, torch::kDouble)));
        // <G x, v> = <x, Gᵀ v>, with Gᵀ from the custom backward.
        auto a = torch::rand({2, 2, 30, 41}, torch::kDouble).requires_grad_(true);
        auto v = torch::rand({2, 2, 20, 31}, torch::kDouble);
        auto lhs = (gauss_filter_valid(a) * v).sum();
        lhs.backward();
        CHECK((a.grad() * a).sum().item<double>() ==
              doctest::Approx(lhs.item<double>()).epsilon(1e-12));
        CHECK_THROWS_AS(gauss_filter_valid(torch::rand({1, 1, 10, 40})), Error);
    }
    SUBCASE("the loss, float as trained, 5 and 3 scales, gradients to both images") {
        for (auto hw : {std::array<int64_t, 2>{180, 200}, std::array<int64_t, 2>{48, 70}}) {
            auto b0 = torch::rand({2, 3, hw[0], hw[1]});
            auto a0 = (b0 + 0.2 * torch::randn({2, 3, hw[0], hw[1]})).clamp(0, 1);
            auto a = a0.clone().requires_grad_(true), b = b0.clone().requires_grad_(true);
            auto fast = ms_ssim_loss(a, b);
            fast.backward();
            auto ga = a.grad().clone(), gb = b.grad().clone();
            a.mutable_grad().zero_();
            b.mutable_grad().zero_();
            auto ref = ms_ssim_loss_reference(a, b);
            ref.backward();
            INFO("size " << hw[0] << "x" << hw[1]);
            CHECK(fast.item<double>() > 0.05);
            CHECK(fast.item<double>() == doctest::Approx(ref.item<double>()).epsilon(1e-5));
            const double scale = a.grad().abs().max().item<double>();
            CHECK(scale > 0);
            CHECK((ga - a.grad()).abs().max().item<double>() < 1e-4 * scale);
            CHECK((gb - b.grad()).abs().max().item<double>() < 1e-4 * scale);
            CHECK(ms_ssim_loss(b0, b0).item<double>() == doctest::Approx(0.0).epsilon(1e-6));
        }
    }
}

TEST_CASE(
    "weighted TV: each difference weighs its two pixels' mean weight, broadcast over channels") {
    auto x = torch::rand({1, 3, 9, 12}, torch::kDouble);
    CHECK(tv_l1(x, torch::ones({1, 1, 9, 12}, torch::kDouble)).item<double>() ==
          doctest::Approx(tv_l1(x).item<double>()).epsilon(1e-12));
    CHECK(tv_l1(x, torch::full({1, 1, 9, 12}, 3.0, torch::kDouble)).item<double>() ==
          doctest::Approx(3 * tv_l1(x).item<double>()).epsilon(1e-12));
    // A ramp along x (step 1 per px) under a weight of 1 on the left half and 3 on the right:
    // the difference across the boundary weighs 2.
    auto ramp =
        torch::arange(4, torch::kDouble).view({1, 1, 1, 4}).expand({1, 1, 2, 4}).contiguous();
    auto w =
        torch::tensor({1.0, 1.0, 3.0, 3.0}, torch::kDouble).view({1, 1, 1, 4}).expand({1, 1, 2, 4});
    CHECK(tv_l1(ramp, w).item<double>() == doctest::Approx((1.0 + 2.0 + 3.0) / 3.0).epsilon(1e-12));
}

TEST_CASE(
    "TV by the radii a texel was seen at: one radius in every view weighs more, a focus change "
    "does not") {
    // Texels: seen at 3 px in every view; at 0.5 px everywhere; sharpest 0.2 px but over 0.2..6 px
    // (a focus pull); at 9 px everywhere (capped); at 2 px with a spread of 0.5 px (half-way).
    auto sharp = torch::tensor({3.0, 0.5, 0.2, 9.0, 2.0}, torch::kDouble);
    auto mean = torch::tensor({3.0, 0.5, 3.0, 9.0, 2.0}, torch::kDouble);
    auto sd = torch::tensor({0.0, 0.0, 2.0, 0.0, 0.5}, torch::kDouble);
    auto f = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 1.0, 4.0, 1.0);
    CHECK(f[0].item<double>() == doctest::Approx(3.0));
    CHECK(f[1].item<double>() == doctest::Approx(1.0));
    CHECK(f[2].item<double>() == doctest::Approx(1.0));
    CHECK(f[3].item<double>() == doctest::Approx(4.0));
    CHECK(f[4].item<double>() == doctest::Approx(1.5));
    auto g2 = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 2.0, 4.0, 1.0);
    CHECK(g2[1].item<double>() == doctest::Approx(1.0));
    CHECK(g2[0].item<double>() == doctest::Approx(4.0));
    CHECK(tv_radius_factor(sharp, mean, mean * mean, 1.0, 1.0, 1.0).eq(1.0).all().item<bool>());
    // Deep blur fades back to 1: 9 px is past a fade at 5; 3 px is not; 4.5 px is half-way.
    auto faded = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 1.0, 4.0, 1.0, 5.0);
    CHECK(faded[0].item<double>() == doctest::Approx(3.0));
    CHECK(faded[3].item<double>() == doctest::Approx(1.0));
    auto half = tv_radius_factor(torch::full({1}, 4.5, torch::kDouble),
                                 torch::full({1}, 4.5, torch::kDouble),
                                 torch::full({1}, 4.5 * 4.5, torch::kDouble), 1.0, 4.0, 1.0, 5.0);
    CHECK(half[0].item<double>() == doctest::Approx(1.0 + 3.0 * 0.5));
}
