// The lens blur layer (paper §3.3): stability, identity limit, gradients, adjoint, energy and
// border rule, agreement with the slow reference and the tensor-ops version, bad input.
#include <ATen/Parallel.h>
#include <torch/torch.h>
// LibTorch pulls in glog, whose CHECK would shadow doctest's.
#undef CHECK
#include <doctest/doctest.h>

#include <cmath>
#include <string>

#include "ops/lens_blur.h"
#include "ops/uniform_blur.h"
#include "util/error.h"

using refocus::BlurKernel;
using refocus::coc_second_moment;
using refocus::kernel_radius_for_coc;
using refocus::lens_blur;
using refocus::LensBlurParams;

namespace {

const BlurKernel kAllKernels[] = {BlurKernel::Disk, BlurKernel::Pillbox, BlurKernel::Gaussian};

const char* name(BlurKernel k) {
    return k == BlurKernel::Disk ? "disk" : k == BlurKernel::Pillbox ? "pillbox" : "gaussian";
}

LensBlurParams params_for(BlurKernel k, double beta = 2.0) {
    LensBlurParams p;
    p.kernel = k;
    p.beta = beta;
    return p;
}

double max_abs(const torch::Tensor& t) {
    return t.abs().max().item<double>();
}

// A radius map with zeros, the identity range, the blend range, fractional and large values.
torch::Tensor mixed_radius(int H, int W, double large, uint64_t seed) {
    torch::manual_seed(seed);
    torch::Tensor r = torch::rand({H, W}, torch::kDouble) * large;
    auto a = r.accessor<double, 2>();
    const double fixed[] = {0.0, 0.0, 0.1, 0.25, 0.4, 0.6, 1.3, 2.7, large};
    for (int i = 0; i < 9; ++i) a[(i * 5) % H][(i * 7) % W] = fixed[i];
    for (int x = 0; x < W; ++x) a[H / 2][x] = 0;  // a sharp row
    return r;
}

// Σ out·w with a fixed random w: a scalar whose gradient is the backward pass.
double loss(const torch::Tensor& img, const torch::Tensor& r, const torch::Tensor& w,
            const LensBlurParams& p) {
    return (lens_blur(img, r, p) * w).sum().item<double>();
}

std::string thrown_message(const std::function<void()>& f) {
    try {
        f();
    } catch (const refocus::Error& e) {
        return e.what();
    }
    return "";
}

}  // namespace

TEST_CASE("beta <= 1/e and bad parameters are refused with a clear error") {
    torch::Tensor img = torch::rand({3, 8, 8});
    torch::Tensor r = torch::full({8, 8}, 2.0f);
    for (double beta : {std::exp(-1.0), 0.36, 0.0, -2.0}) {
        std::string msg =
            thrown_message([&] { lens_blur(img, r, params_for(BlurKernel::Disk, beta)); });
        CHECK(msg.find("beta > 1/e") != std::string::npos);
    }
    CHECK_NOTHROW(lens_blur(img, r, params_for(BlurKernel::Disk, std::exp(-1.0) + 1e-6)));
    LensBlurParams g = params_for(BlurKernel::Gaussian);
    g.kappa = 0;
    CHECK(thrown_message([&] { lens_blur(img, r, g); }).find("kappa > 0") != std::string::npos);
    LensBlurParams m;
    m.min_radius = -1;
    CHECK_THROWS_AS(lens_blur(img, r, m), refocus::Error);
}

TEST_CASE("no overflow, NaN or Inf for r in 0..64 px and any beta > 1/e") {
    const int H = 24, W = 30;
    torch::Tensor r = torch::linspace(0, 64, H * W, torch::kDouble).view({H, W});
    torch::manual_seed(3);
    torch::Tensor img = torch::rand({3, H, W}, torch::kDouble);
    for (double beta : {std::exp(-1.0) + 1e-9, 0.5, 2.0, 10.0, 1000.0}) {
        for (auto dtype : {torch::kFloat, torch::kDouble}) {
            CAPTURE(beta);
            torch::Tensor x = img.to(dtype).detach().clone().requires_grad_(true);
            torch::Tensor rr = r.to(dtype).detach().clone().requires_grad_(true);
            torch::Tensor out = lens_blur(x, rr, params_for(BlurKernel::Disk, beta));
            CHECK(out.isfinite().all().item<bool>());
            CHECK(out.min().item<double>() >= 0);  // positive kernel on a positive image
            out.mul(torch::rand_like(out)).sum().backward();
            CHECK(x.grad().isfinite().all().item<bool>());
            CHECK(rr.grad().isfinite().all().item<bool>());
            // Energy is kept at every β (rtol 1e-5 in float, 1e-12 in double).
            double tol = dtype == torch::kFloat ? 1e-5 : 1e-12;
            CHECK(std::abs(out.sum().item<double>() / x.sum().item<double>() - 1) < tol);
        }
    }
}

TEST_CASE("r -> 0 is the identity: exact at r = 0 and 0.25, stated tolerance at 0.5") {
    // min_radius = 0.25 (default), blend over 0.25 < r < 0.75. On a unit impulse the deviation
    // from the identity is 1 − (centre weight); measured at r = 0.5 (s = ½): disk 0.339,
    // pillbox 0, gaussian 0.279 (β = 2, κ = 1.2); asserted below, and r = 0.25 + 1e-3 is
    // within 1e-5 of the identity (the blend is C¹ and starts flat).
    const double tol_half[] = {0.34, 1e-12, 0.28};
    torch::Tensor img = torch::zeros({1, 15, 15}, torch::kDouble);
    img[0][7][7] = 1.0;
    torch::manual_seed(11);
    torch::Tensor rnd = torch::rand({3, 15, 15}, torch::kDouble);
    int i = 0;
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        for (double r0 : {0.0, 0.1, 0.25}) {
            torch::Tensor r = torch::full({15, 15}, r0, torch::kDouble);
            CHECK(max_abs(lens_blur(rnd, r, p) - rnd) == 0.0);  // one tap
        }
        torch::Tensor r = torch::full({15, 15}, 0.25 + 1e-3, torch::kDouble);
        CHECK(max_abs(lens_blur(img, r, p) - img) < 1e-5);
        r.fill_(0.5);
        double dev = max_abs(lens_blur(img, r, p) - img);
        CHECK(dev <= tol_half[i]);
        // Monotone approach: the deviation shrinks as r falls towards min_radius.
        r.fill_(0.4);
        CHECK(max_abs(lens_blur(img, r, p) - img) <= dev + 1e-15);
        ++i;
    }
}

TEST_CASE("radius gradient is finite at r = 0 and across the identity/blend boundary") {
    torch::manual_seed(5);
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        torch::Tensor img = torch::rand({3, 12, 12}, torch::kDouble);
        for (double r0 : {0.0, 0.25, 0.25 + 1e-9, 0.3, 0.75}) {
            torch::Tensor r = torch::full({12, 12}, r0, torch::kDouble).requires_grad_(true);
            lens_blur(img, r, params_for(k))
                .mul(torch::rand({3, 12, 12}, torch::kDouble))
                .sum()
                .backward();
            CHECK(r.grad().isfinite().all().item<bool>());
            if (r0 <= 0.25) CHECK(max_abs(r.grad()) == 0.0);         // identity: exactly flat
            if (r0 == 0.25 + 1e-9) CHECK(max_abs(r.grad()) < 1e-6);  // C¹ blend starts flat
        }
    }
}

TEST_CASE("image gradient matches finite differences (float64)") {
    const int C = 3, H = 20, W = 24;
    torch::Tensor r = mixed_radius(H, W, 9.0, 21);
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        torch::manual_seed(7);
        torch::Tensor img = torch::rand({C, H, W}, torch::kDouble).requires_grad_(true);
        torch::Tensor w = torch::randn({C, H, W}, torch::kDouble);
        (lens_blur(img, r, p) * w).sum().backward();
        torch::Tensor g = img.grad();
        torch::Tensor x = img.detach().clone();
        auto xa = x.accessor<double, 3>();
        double worst = 0;
        const double h = 1e-4;  // the map is linear in the image: only rounding error remains
        for (int i = 0; i < 60; ++i) {
            int c = i % C, y = (i * 7) % H, xx = (i * 13) % W;
            double v = xa[c][y][xx];
            xa[c][y][xx] = v + h;
            double lp = loss(x, r, w, p);
            xa[c][y][xx] = v - h;
            double lm = loss(x, r, w, p);
            xa[c][y][xx] = v;
            worst = std::max(worst, std::abs((lp - lm) / (2 * h) - g[c][y][xx].item<double>()));
        }
        CHECK(worst < 1e-8);
    }
}

TEST_CASE("radius gradient matches finite differences on every pixel (float64)") {
    // Radius maps with 0, the identity and blend ranges, fractional values and up to 9 px
    // (support beyond the 24x20 frame, so the border rule is differentiated too).
    const int C = 3, H = 20, W = 24;
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        torch::Tensor r = mixed_radius(H, W, 9.0, 31).requires_grad_(true);
        torch::manual_seed(8);
        torch::Tensor img = torch::rand({C, H, W}, torch::kDouble);
        torch::Tensor w = torch::randn({C, H, W}, torch::kDouble);
        (lens_blur(img, r, p) * w).sum().backward();
        torch::Tensor g = r.grad().clone();
        torch::Tensor rr = r.detach().clone();
        auto ra = rr.accessor<double, 2>();
        const double h = 1e-6;
        double worst = 0, scale = max_abs(g);
        int bad = 0;
        for (int y = 0; y < H; ++y) {
            for (int x = 0; x < W; ++x) {
                double v = ra[y][x];
                if (v > 0.25 - h && v < 0.25 + h)
                    continue;  // on the identity boundary (kink-free
                               // but one-sided FD is not needed)
                ra[y][x] = v + h;
                double lp = loss(img, rr, w, p);
                ra[y][x] = std::max(0.0, v - h);
                double lm = loss(img, rr, w, p);
                ra[y][x] = v;
                double fd = (lp - lm) / (v + h - std::max(0.0, v - h));
                double err = std::abs(fd - g[y][x].item<double>());
                worst = std::max(worst, err);
                // Pillbox and the truncated disk are C⁰ in r at a few isolated radii (a tap at
                // the edge of the linear ramp / support): allow a very rare kink hit.
                if (err > 1e-6 * (1 + scale)) ++bad;
            }
        }
        CAPTURE(worst);
        CAPTURE(scale);
        CHECK(scale > 1e-3);  // the gradient is not trivially zero
        CHECK(bad <= 1);
    }
}

TEST_CASE("adjoint: <Hx, y> = <x, H*y>") {
    const int C = 3, H = 37, W = 45;  // several tiles, odd sizes
    torch::manual_seed(13);
    torch::Tensor r = torch::rand({H, W}, torch::kDouble) * 10;
    r.narrow(1, 0, 10).zero_();
    torch::Tensor x = torch::randn({C, H, W}, torch::kDouble);
    torch::Tensor y = torch::randn({C, H, W}, torch::kDouble);
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        for (auto dtype : {torch::kDouble, torch::kFloat}) {
            torch::Tensor xd = x.to(dtype), yd = y.to(dtype), rd = r.to(dtype);
            double lhs = (lens_blur(xd, rd, p) * yd).sum().item<double>();
            double rhs = (xd * refocus::lens_blur_adjoint(yd, rd, p)).sum().item<double>();
            double rel = std::abs(lhs - rhs) / std::max(std::abs(lhs), 1e-30);
            CHECK(rel < (dtype == torch::kDouble ? 1e-12 : 1e-5));
        }
        // The adjoint is the image gradient of the forward.
        torch::Tensor xg = x.clone().requires_grad_(true);
        (lens_blur(xg, r, p) * y).sum().backward();
        CHECK(max_abs(xg.grad() - refocus::lens_blur_adjoint(y, r, p)) < 1e-14);
    }
}

TEST_CASE("energy: sum out = sum in away from borders, and the border rule") {
    torch::manual_seed(17);
    const int H = 40, W = 50;
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        // Away from borders: an image that is zero within 16 px of the frame, r ≤ 6.
        torch::Tensor img = torch::zeros({3, H, W}, torch::kDouble);
        img.narrow(1, 16, H - 32).narrow(2, 16, W - 32).uniform_();
        torch::Tensor r = torch::rand({H, W}, torch::kDouble) * 6;
        torch::Tensor out = lens_blur(img, r, p);
        for (int c = 0; c < 3; ++c)
            CHECK(std::abs(out[c].sum().item<double>() - img[c].sum().item<double>()) < 1e-12);
        // A constant image with a constant radius stays constant at least two supports (the
        // Gaussian's is 4·1.2·2.5 = 12 px) from the borders, where no source is clipped.
        torch::Tensor flat = torch::full({1, 80, 90}, 0.7, torch::kDouble);
        torch::Tensor rc = torch::full({80, 90}, 2.5, torch::kDouble);
        torch::Tensor fo = lens_blur(flat, rc, p);
        CHECK(max_abs(fo.narrow(1, 25, 30).narrow(2, 25, 40) - 0.7) < 1e-12);

        // Border rule: taps outside the frame are dropped and the kernel is renormalised over
        // the in-image taps, so nothing leaves the frame even from the corner pixel.
        torch::Tensor r_all = torch::rand({H, W}, torch::kDouble) * 12;
        torch::Tensor full = torch::rand({3, H, W}, torch::kDouble);
        torch::Tensor fout = lens_blur(full, r_all, p);
        for (int c = 0; c < 3; ++c)
            CHECK(std::abs(fout[c].sum().item<double>() / full[c].sum().item<double>() - 1) <
                  1e-12);
        torch::Tensor corner = torch::zeros({1, H, W}, torch::kDouble);
        corner[0][0][0] = 1.0;
        torch::Tensor r8 = torch::full({H, W}, 8.0, torch::kDouble);
        torch::Tensor co = lens_blur(corner, r8, p);
        CHECK(std::abs(co.sum().item<double>() - 1) < 1e-12);
        // The corner keeps about 4x the weight an interior centre gets (a quarter disk).
        torch::Tensor mid = torch::zeros({1, H, W}, torch::kDouble);
        mid[0][20][25] = 1.0;
        torch::Tensor mo = lens_blur(mid, r8, p);
        double ratio = co[0][0][0].item<double>() / mo[0][20][25].item<double>();
        CHECK(ratio > 3.0);
        CHECK(ratio < 4.5);
        // Interior impulse response is symmetric.
        CHECK(max_abs(mo - mo.flip({1}).roll(1, 1)) < 1e-14);
    }
}

TEST_CASE("fast path matches the slow reference on random inputs, all kernels") {
    // 70x40 spans several 32x32 tiles (tile skipping + borders), with a sharp left third.
    const int H = 40, W = 70;
    torch::manual_seed(23);
    torch::Tensor r = torch::rand({H, W}, torch::kDouble) * 7;
    r.narrow(1, 0, 24).mul_(0.03);  // below min_radius: whole identity tiles
    r[5][50] = 0;
    r[30][60] = 0.5;
    for (BlurKernel k : kAllKernels) {
        for (double beta : {0.5, 2.0, 8.0}) {
            if (k != BlurKernel::Disk && beta != 2.0) continue;
            CAPTURE(name(k));
            CAPTURE(beta);
            LensBlurParams p = params_for(k, beta);
            for (int C : {1, 2, 3}) {
                torch::Tensor img = torch::rand({C, H, W}, torch::kDouble);
                torch::Tensor ref = refocus::lens_blur_reference(img, r, p);
                CHECK(max_abs(lens_blur(img, r, p) - ref) < 1e-12);
                torch::Tensor f32 = lens_blur(img.to(torch::kFloat), r.to(torch::kFloat), p);
                CHECK(max_abs(f32.to(torch::kDouble) - ref) < 5e-6);
            }
        }
    }
}

TEST_CASE("tensor-ops version agrees with the fast path, values and gradients") {
    const int H = 20, W = 24;
    torch::Tensor r0 = mixed_radius(H, W, 5.0, 41);
    torch::manual_seed(43);
    torch::Tensor img0 = torch::rand({3, H, W}, torch::kDouble);
    torch::Tensor w = torch::randn({3, H, W}, torch::kDouble);
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        LensBlurParams p = params_for(k);
        torch::Tensor a_img = img0.clone().requires_grad_(true),
                      a_r = r0.clone().requires_grad_(true);
        torch::Tensor b_img = img0.clone().requires_grad_(true),
                      b_r = r0.clone().requires_grad_(true);
        torch::Tensor a = lens_blur(a_img, a_r, p);
        torch::Tensor b = refocus::lens_blur_tensor_ops(b_img, b_r, p);
        CHECK(max_abs(a - b) < 1e-12);
        (a * w).sum().backward();
        (b * w).sum().backward();
        CHECK(max_abs(a_img.grad() - b_img.grad()) < 1e-12);
        CHECK(max_abs(a_r.grad() - b_r.grad()) < 1e-10);
    }
}

TEST_CASE("result does not depend on the thread count") {
    torch::manual_seed(47);
    torch::Tensor img = torch::rand({3, 64, 96}, torch::kDouble);
    torch::Tensor r = torch::rand({64, 96}, torch::kDouble) * 8;
    int saved = at::get_num_threads();
    at::set_num_threads(1);
    torch::Tensor one = lens_blur(img, r);
    at::set_num_threads(std::max(2, saved));
    torch::Tensor many = lens_blur(img, r);
    at::set_num_threads(saved);
    CHECK(max_abs(one - many) < 1e-13);
}

TEST_CASE("NaN/Inf and negative radii are reported, not spread") {
    torch::Tensor img = torch::rand({3, 10, 12});
    torch::Tensor r = torch::full({10, 12}, 2.0f);
    torch::Tensor bad = img.clone();
    bad[1][2][3] = std::nanf("");
    std::string m = thrown_message([&] { lens_blur(bad, r); });
    CHECK(m.find("non-finite") != std::string::npos);
    CHECK(m.find("channel 1, pixel (x 3, y 2)") != std::string::npos);
    bad[1][2][3] = INFINITY;
    CHECK(thrown_message([&] { lens_blur(bad, r); }).find("image") != std::string::npos);
    torch::Tensor rb = r.clone();
    rb[4][5] = -INFINITY;
    m = thrown_message([&] { lens_blur(img, rb); });
    CHECK(m.find("radius") != std::string::npos);
    CHECK(m.find("(x 5, y 4)") != std::string::npos);
    rb[4][5] = -0.5f;
    CHECK(thrown_message([&] { lens_blur(img, rb); }).find(">= 0") != std::string::npos);
    CHECK(thrown_message([&] { refocus::lens_blur_adjoint(bad, r); }).find("non-finite") !=
          std::string::npos);
    // A NaN arriving in the backward pass is reported as well.
    torch::Tensor x = img.clone().requires_grad_(true);
    torch::Tensor g = torch::ones_like(img);
    g[0][0][0] = NAN;
    CHECK_THROWS_AS(lens_blur(x, r).backward(g), refocus::Error);
    // Shapes.
    CHECK_THROWS_AS(lens_blur(img, torch::zeros({10, 11})), refocus::Error);
    CHECK_THROWS_AS(lens_blur(img[0], r), refocus::Error);
}

TEST_CASE("a circle of confusion becomes the kernel radius that spreads light as far") {
    // The operator's own point spread function at kernel_radius_for_coc(c) has the second
    // moment of a uniform disk of radius c imaged onto the pixel grid (c²/2 plus the bilinear
    // tent's share, 1/3 px² once the disk spans pixels), for every kernel.
    CHECK(coc_second_moment(0.0) == 0.0);
    // Inside one pixel (|a| < 1) each axis adds |a|: twice E|a| = 4c/3π over the disk.
    CHECK(coc_second_moment(0.2) == doctest::Approx(8 * 0.2 / (3 * M_PI)).epsilon(0.01));
    for (double c : {3.0, 7.0, 12.0})
        CHECK(coc_second_moment(c) == doctest::Approx(0.5 * c * c + 1.0 / 3.0).epsilon(0.002));
    for (BlurKernel kernel : {BlurKernel::Disk, BlurKernel::Pillbox, BlurKernel::Gaussian}) {
        LensBlurParams p;
        p.kernel = kernel;
        double last = 0;
        for (double c : {1.0, 3.0, 7.0, 12.0}) {
            const double r = kernel_radius_for_coc(c, p);
            CHECK(r > last);  // monotone
            last = r;
            const int n = 2 * int(c + 8 + 4 * p.kappa * c * (kernel == BlurKernel::Gaussian)) + 1,
                      mid = n / 2;
            auto img = torch::zeros({1, n, n}, torch::kFloat64);
            img[0][mid][mid] = 1.0;
            auto psf = lens_blur(img, torch::full({n, n}, r, torch::kFloat64), p)[0];
            auto ys = torch::arange(n, torch::kFloat64) - mid;
            auto rho2 = ys.view({n, 1}).pow(2) + ys.view({1, n}).pow(2);
            const double m2 = (psf * rho2).sum().item<double>() / psf.sum().item<double>();
            CHECK(m2 == doctest::Approx(coc_second_moment(c)).epsilon(0.02));
        }
    }
    CHECK(kernel_radius_for_coc(0.0) == 0.0);
    // The disk's soft edge makes it wider than the disk of its radius.
    CHECK(kernel_radius_for_coc(7.0) == doctest::Approx(6.36).epsilon(0.01));
}

TEST_CASE("uniform radii by FFT match the direct blur away from the border, all kernels") {
    // The focal-stack radius estimate blurs at every radius of its grid this way
    // (ops/uniform_blur.h): its reference path is lens_blur itself.
    torch::manual_seed(7);
    const int64_t H = 61, W = 83;
    const auto img = torch::rand({3, H, W});
    const std::vector<double> radii{0.0, 0.2, 0.6, 1.5, 4.0, 9.5};
    for (BlurKernel k : kAllKernels) {
        CAPTURE(name(k));
        const LensBlurParams p = params_for(k);
        const refocus::UniformBlurBank bank(H, W, radii, p);
        const auto spec = bank.spectrum(img);
        for (size_t i = 0; i < radii.size(); ++i) {
            CAPTURE(radii[i]);
            const auto direct = lens_blur(img, torch::full({H, W}, float(radii[i])), p);
            const auto fft = bank.blur(spec, i);
            REQUIRE(fft.sizes() == direct.sizes());
            // A source within R_s of the border has its spread renormalised (lens_blur.h), and
            // it reaches R_s further in: the two agree beyond twice the support.
            const int64_t m = 2 * (int64_t(std::ceil(refocus::lens_blur_support(radii[i], p))) + 1);
            if (2 * m < H) {
                const auto in = [&](const torch::Tensor& x) {
                    return x.narrow(1, m, H - 2 * m).narrow(2, m, W - 2 * m);
                };
                CHECK((in(fft)-in(direct)).abs().max().item<double>() < 2e-5);
            }
            // Near the border both keep a flat image flat and stay within the image's range.
            const auto flat = bank.blur(bank.spectrum(torch::full({1, H, W}, 0.3f)), i);
            CHECK((flat - 0.3).abs().max().item<double>() < 2e-5);
            CHECK(fft.min().item<double>() > -1e-4);
            CHECK(fft.max().item<double>() < 1.0 + 1e-4);
        }
    }
    CHECK_THROWS_AS(refocus::UniformBlurBank(H, W, {-1.0}, LensBlurParams{}), refocus::Error);
    const refocus::UniformBlurBank bank(H, W, {2.0}, LensBlurParams{});
    CHECK_THROWS_AS(bank.spectrum(torch::zeros({3, H + 1, W})), refocus::Error);
}
