// The fast model: its padded render, the footprint prefilter, the shake search of a static
// camera, the 2x atlas of a moving camera and the deblurring path.
#include <nlohmann/json.hpp>
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <cmath>
#include <cstdlib>
#include <map>

#include "model/atlas_geometry.h"
#include "fit/fast_model.h"
#include "fit/fit_engine.h"
#include "fit/fit_setup.h"
#include "util/error.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE(
    "fast model renders a margin past the frame edge; the reblur crops it back; checkpoints keep "
    "the figures") {
    // Near an edge the lens gathered light from outside the frame: the atlas reaches past it by
    // the widest blur support, and training blurs the padded render (FitModel::render_padded).
    const int64_t T = 3, H = 24, W = 32;
    torch::manual_seed(0);
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->input = torch::rand({T, 3, H, W});
    d->radius = torch::full({T, H, W}, 2.0);
    d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    FitOptions o;
    o.preset = "fast";
    o.iters = 1;
    FitEngine e(d, o);
    const int64_t P = e.model().max_pad();
    REQUIRE(P >= 3);  // support of a 2 px disk plus its soft edge
    Layers a = e.model().render({0, 2}), b = e.model().render_padded({0, 2}, P);
    REQUIRE(b.sharp.size(2) == H + 2 * P);
    REQUIRE(b.sharp.size(3) == W + 2 * P);
    CHECK(torch::allclose(b.sharp.narrow(2, P, H).narrow(3, P, W), a.sharp, 1e-5, 1e-5));
    // The margin starts as the frame's edge carried outward.
    CHECK((b.sharp.select(3, 0) - b.sharp.select(3, P)).abs().max().item<double>() < 1e-4);
    CHECK((b.sharp.select(2, H + 2 * P - 1) - b.sharp.select(2, P + H - 1))
              .abs()
              .max()
              .item<double>() < 1e-4);
    auto rb = e.reblur(b, {0, 2}), rb0 = e.reblur(a, {0, 2});
    REQUIRE(rb.sizes() == rb0.sizes());
    // Two supports from the edges the two agree; at the edge they differ.
    auto inner = [&](const torch::Tensor& x) {
        return x.narrow(2, 2 * P, H - 4 * P).narrow(3, 2 * P, W - 4 * P);
    };
    CHECK(torch::allclose(inner(rb), inner(rb0), 1e-4, 1e-4));
    CHECK(!torch::allclose(rb.select(3, 0), rb0.select(3, 0), 1e-3, 1e-3));
    CHECK(torch::isfinite(rb).all().item<bool>());
    CHECK_THROWS_WITH_AS(e.model().render_padded({0}, P + 1), doctest::Contains("padding"), Error);
    e.step();
    CHECK(e.snapshot().step == 1);

    // A checkpoint keeps the last step's figures: a reopened project shows them, not zeros.
    const fs::path ck = scratch_dir("fit_checkpoint_figures");
    e.save_checkpoint(ck);
    FitEngine e2(d, o);
    e2.load_checkpoint(ck);
    CHECK(e2.snapshot().step == 1);
    CHECK(e2.snapshot().loss == doctest::Approx(e.snapshot().loss));
    CHECK(e2.snapshot().loss > 0);
    CHECK(e2.snapshot().reblur_psnr == doctest::Approx(e.snapshot().reblur_psnr));
    CHECK(e2.snapshot().terms.count("l1") == 1);
}

TEST_CASE("a subject seen smaller than in its atlas: the atlas is prefiltered for the footprint") {
    // A point spreads to the footprint's box variance less the texel's own: (s² − 1)/12 a side.
    auto impulse = torch::zeros({1, 3, 21, 21});
    impulse.index_put_({0, torch::indexing::Slice(), 10, 10}, 1.0f);
    for (double s : {1.5, 2.5, 4.0}) {
        auto f = prefilter_for_footprint(impulse, s);
        REQUIRE(f.sizes() == impulse.sizes());
        auto x = torch::arange(-10, 11, torch::kFloat32);
        const double sum = f[0][1].sum().item<double>();
        const double var_x = (f[0][1] * (x * x).view({1, 21})).sum().item<double>() / sum;
        const double var_y = (f[0][1] * (x * x).view({21, 1})).sum().item<double>() / sum;
        INFO("s " << s << ": variance " << var_x << " x " << var_y);
        CHECK(sum == doctest::Approx(1.0).epsilon(1e-5));  // light is kept
        CHECK(var_x == doctest::Approx((s * s - 1) / 12).epsilon(0.03));
        CHECK(var_y == doctest::Approx(var_x).epsilon(1e-5));
    }
    // No minification (or a magnification): the atlas as it is; a flat atlas stays flat.
    // The shifted-slice taps against LibTorch's depthwise conv2d, with gradients.
    for (double s : {1.2, 1.9, 2.5, 4.0}) {
        auto img = torch::rand({1, 3, 37, 53}, torch::requires_grad());
        auto a = prefilter_for_footprint(img, s), b = prefilter_for_footprint_reference(img, s);
        CHECK(torch::allclose(a, b, 1e-6, 1e-6));
        auto w = torch::rand_like(a);
        auto ga = torch::autograd::grad({(a * w).sum()}, {img})[0];
        auto gb = torch::autograd::grad({(b * w).sum()}, {img})[0];
        CHECK(torch::allclose(ga, gb, 1e-5, 1e-5));
    }
    CHECK(prefilter_for_footprint(impulse, 1.0).is_same(impulse));
    CHECK(prefilter_for_footprint(impulse, 0.5).is_same(impulse));
    auto flat = torch::full({1, 3, 9, 12}, 0.4f);
    CHECK((prefilter_for_footprint(flat, 3.0) - 0.4f).abs().max().item<float>() < 1e-6f);

    // A subject walking away (masks given: 8 frames of a tiny clip are too few for automatic
    // ones): the fit says that it prefilters, and its sharp frames stay finite.
    TinyClip c = make_tiny("fit_walkaway", "walkout", "160x90");
    RunResult r = cli("fit '" + c.project.string() + "' --preset fast --iters 3 --coc '" +
                      (c.clip / "coc_%04d.exr").string() + "' --mask '" +
                      (c.clip / "alpha_%04d.png").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("the subject's size changes along the clip") != std::string::npos);
    CHECK(r.output.find("prefiltered for each frame where the subject is smaller") !=
          std::string::npos);
    for (const auto& img : export_sharp(c, "sharp"))
        for (float v : img.pixels) REQUIRE(std::isfinite(v));
}

TEST_CASE("a static camera's hand shake is found; a locked-off camera keeps the identity") {
    // Prepare calls a camera static when its feature homographies move the corners < 2 px, and
    // the fit then maps frames by the identity. A hand-held shot shakes by a pixel (synth walkout:
    // 1.5 px, which cost it 0.4 dB); the ECC pass against the reblurred atlas finds the shake.
    const int64_t H = 48, W = 64;
    torch::manual_seed(4);
    namespace F = torch::nn::functional;
    auto texture = F::interpolate(torch::rand({1, 3, H / 3, W / 3}),
                                  F::InterpolateFuncOptions()
                                      .size(std::vector<int64_t>{H + 16, W + 16})
                                      .mode(torch::kBilinear)
                                      .align_corners(false));
    // Five frames (a short clip: every frame aligned), then 60 (a long one: a sample first).
    int64_t T = 5;
    std::vector<double> sx = {0.0, 0.9, -1.2, 0.5, 1.4}, sy = {0.0, -0.6, 0.8, 1.1, -0.4};
    auto make = [&](bool shake) {
        auto d = std::make_shared<FitData>();
        d->frames = T, d->height = H, d->width = W;
        std::vector<torch::Tensor> frames;
        for (int64_t t = 0; t < T; ++t) {
            // Frame pixel (x, y) shows the texture at (x + 8 + sx, y + 8 + sy).
            const double dx = shake ? sx[t] : 0.0, dy = shake ? sy[t] : 0.0;
            auto ys = (torch::arange(H, torch::kFloat32) + 8.0 + dy + 0.5) * (2.0 / (H + 16)) - 1.0;
            auto xs = (torch::arange(W, torch::kFloat32) + 8.0 + dx + 0.5) * (2.0 / (W + 16)) - 1.0;
            auto g = torch::meshgrid({ys, xs}, "ij");
            auto grid = torch::stack({g[1], g[0]}, -1).unsqueeze(0);
            auto f = F::grid_sample(
                texture, grid,
                F::GridSampleFuncOptions().mode(torch::kBilinear).align_corners(false))[0];
            frames.push_back(lens_blur(f.contiguous(), torch::full({H, W}, 1.0f), d->blur));
        }
        d->input = torch::stack(frames);
        d->radius = torch::full({T, H, W}, 1.0f);
        d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
        d->static_camera = true;
        return d;
    };
    FastModelOptions o;
    auto check = [&] {
        {
            auto d = make(true);
            FastModel m(*d, o);
            auto A = m.state().at("bg_to_atlas");
            // A long clip's frames: within 0.15 px on average, 0.3 at most (a frame shaken by
            // under 0.3 px may keep the identity).
            double sum = 0;
            for (int64_t t = 1; t < T; ++t) {
                const double ex = A[t][0][2].item<double>() - A[0][0][2].item<double>();
                const double ey = A[t][1][2].item<double>() - A[0][1][2].item<double>();
                INFO("frame " << t << ": found (" << ex << ", " << ey << "), shaken by (" << sx[t]
                              << ", " << sy[t] << ")");
                const double e = std::max(std::abs(ex - sx[t]), std::abs(ey - sy[t]));
                CHECK(e < (T > 48 ? 0.3 : 0.15));
                sum += e;
            }
            CHECK(sum / double(T - 1) < 0.15);
        }
        {
            auto d = make(false);
            FastModel m(*d, o);
            auto A = m.state().at("bg_to_atlas");
            CHECK(torch::equal(
                A, A[0].expand_as(A)));  // exactly the identity (up to the atlas origin)
            CHECK(A[0][0][0].item<double>() == 1.0);
            CHECK(A[0][0][1].item<double>() == 0.0);
            const bool noted = std::any_of(
                m.notes.begin(), m.notes.end(),
                [](const std::string& n) { return n.find("locked off") != std::string::npos; });
            CHECK(noted == (T > 48));  // a long clip's sample said so
            // A fitted project opened (export): no alignment, the checkpoint's geometry replaces
            // it.
            FastModelOptions opened = o;
            opened.align_rounds = 0;
            opened.restore_only = true;
            CHECK_NOTHROW(FastModel(*d, opened));
        }
    };
    check();
    T = 60;
    sx.assign(T, 0.0), sy.assign(T, 0.0);
    for (int64_t t = 1; t < T; ++t)
        sx[t] = 1.4 * std::sin(1.7 * t), sy[t] = 1.1 * std::cos(2.3 * t);
    check();
}

namespace {
// A pan over a texture with detail up to the frame's Nyquist limit, each frame box-filtered
// from a 4x render (a sensor integrates over its pixel): frame t shows the texture moved by
// `pan` px per frame, at a new sub-pixel phase each time. Returns the data and the sharp frames.
std::pair<std::shared_ptr<FitData>, torch::Tensor> pan_over_detail(int64_t T, double pan,
                                                                   double radius) {
    namespace F = torch::nn::functional;
    const int64_t H = 40, W = 56, S = 4, M = 24;  // M: texture margin, px
    torch::manual_seed(11);
    // Texture at 4x: random 1.5 px cells, nearest-neighbour (hard edges, as glyphs and checkers).
    auto cells = torch::rand({1, 3, (H + 2 * M) * 2 / 3, (W + 2 * M) * 2 / 3});
    auto tex =
        F::interpolate(cells, F::InterpolateFuncOptions()
                                  .size(std::vector<int64_t>{(H + 2 * M) * S, (W + 2 * M) * S})
                                  .mode(torch::kNearest));
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->blur.kernel = BlurKernel::Pillbox;
    std::vector<torch::Tensor> sharp, in, hs;
    for (int64_t t = 0; t < T; ++t) {
        const double dx = pan * t;  // frame pixel x shows the texture at x + M + dx
        const int64_t ox = int64_t(std::floor(dx * S)), oy = M * S;
        auto crop = tex.narrow(2, oy, H * S).narrow(3, M * S + ox, W * S);
        auto f =
            F::avg_pool2d(crop, F::AvgPool2dFuncOptions(S))[0];  // exact for dx on the 1/4 grid
        sharp.push_back(f);
        in.push_back(lens_blur(f.contiguous(), torch::full({H, W}, float(radius)), d->blur));
        hs.push_back(translation(double(ox) / S, 0.0));  // frame t → frame 0's coordinates
    }
    d->input = torch::stack(in);
    d->radius = torch::full({T, H, W}, float(radius));
    d->to_ref = torch::stack(hs).to(torch::kFloat64);
    d->static_camera = false;
    return {d, torch::stack(sharp)};
}

double psnr_of(const torch::Tensor& a, const torch::Tensor& b) {
    return 10 * std::log10(1.0 / (a - b).pow(2).mean().item<double>());
}
}  // namespace

TEST_CASE(
    "a moving camera fits a 2x atlas: detail seen at many sub-pixel phases is resolved; "
    "checkpoints keep the resolution") {
    auto [d, sharp] = pan_over_detail(8, 1.25, 0.4);
    // The decision: a given radius, a moving camera and the clip in focus take 2x; an estimated
    // radius, a static camera, or a clip that nothing shows in focus stay at the frame's
    // resolution.
    CHECK(choose_atlas_scale(*d, true).find("2x") != std::string::npos);
    CHECK(d->atlas_scale == 2);
    {
        FitData s = *d;
        s.static_camera = true;
        choose_atlas_scale(s, true);
        CHECK(s.atlas_scale == 1);
        s = *d;
        s.radius = torch::full_like(d->radius, 4.0f);
        CHECK(choose_atlas_scale(s, true).find("1x") != std::string::npos);
        CHECK(s.atlas_scale == 1);
        s = *d;  // an estimated radius: its errors would be fitted too
        CHECK(choose_atlas_scale(s, false).find("estimated") != std::string::npos);
        CHECK(s.atlas_scale == 1);
        s = *d;  // ... unless focus never changed: the floor, one surface that all frames share
        s.fixed_focus_share = 0.95;
        CHECK(choose_atlas_scale(s, false).find("2x") != std::string::npos);
        CHECK(s.atlas_scale == 2);
    }
    // Texels sit on the frame's pixel centres: the initial (fused) atlas renders each frame back
    // in place, at 2x as closely as at 1x.
    auto fused_err = [&](double scale) {
        FastModelOptions o;
        o.atlas_scale = scale;
        o.align_rounds = 0;
        FastModel m(*d, o);
        torch::NoGradGuard g;
        auto r = m.render({0, 3, 7}).sharp;
        return psnr_of(r, d->input.index_select(0, torch::tensor({0, 3, 7})));
    };
    const double p1 = fused_err(1), p2 = fused_err(2);
    MESSAGE("fused atlas rendered back: 1x " << p1 << " dB, 2x " << p2 << " dB");
    CHECK(p2 > p1 - 0.5);
    CHECK(p2 > 28.0);
    // Fitted: the 2x atlas reproduces the sharp frames better.
    auto fit = [&](double scale, const fs::path& ck) {
        auto data = std::make_shared<FitData>(*d);
        data->atlas_scale = scale;
        FitOptions o;
        o.preset = "fast";
        o.iters = 200;
        FitEngine e(data, o);
        while (!e.done()) e.step();
        std::vector<torch::Tensor> out;
        for (int t = 0; t < data->frames; ++t) out.push_back(e.render_frame(t).sharp[0]);
        if (!ck.empty()) e.save_checkpoint(ck);
        return psnr_of(torch::stack(out).clamp(0, 1), sharp);
    };
    const fs::path ck = scratch_dir("fit_atlas_scale");
    const double f1 = fit(1, {}), f2 = fit(2, ck);
    MESSAGE("fitted, sharp PSNR: input " << psnr_of(d->input, sharp) << " dB, 1x " << f1 << ", 2x "
                                         << f2);
    CHECK(f2 > f1 + 1.0);
    // The checkpoint names its scale; a reopened project takes it whatever this build decides,
    // and a checkpoint of an earlier build (no field) was 1x.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    strip_checksums(j);  // as an earlier build wrote it
    CHECK(j.at("atlas_scale") == 2.0);
    auto reopened = std::make_shared<FitData>(*d);
    reopened->atlas_scale = 1;
    FitOptions o;
    o.preset = "fast";
    o.iters = 200;
    FitEngine e(reopened, o);
    e.load_checkpoint(ck);
    CHECK(e.data().atlas_scale == 2);
    CHECK(e.model().atlas_bg().size(2) > 2 * d->width);
    j.erase("atlas_scale");
    write_file_atomic(ck / "checkpoint.json", j.dump());
    FitEngine old(std::make_shared<FitData>(*d), o);  // this build decides 2x
    old.load_checkpoint(ck);
    CHECK(old.data().atlas_scale == 1);
}

TEST_CASE(
    "the deblurring path: a wall blurred in every frame deblurs faster; it leaves the mean; old "
    "checkpoints load") {
    // A static wall of hard-edged cells seen by 6 frames, each blurred 4 px (8-bit), as a wall
    // that focus never reached. Adam moves each texel by about its learning rate, so the detail
    // the pillbox passed at a few percent comes back slowly through the texels alone; through
    // the path's filter it does not (synth walkout, true radius, 600 steps: 20.15 -> 21.51 dB).
    auto [d, sharp] = pan_over_detail(6, 0.0, 4.0);
    {
        namespace F = torch::nn::functional;
        torch::manual_seed(5);  // cells of 4 px: what a 4 px blur leaves of them can come back
        auto wall = F::interpolate(torch::rand({1, 3, d->height / 4, d->width / 4}),
                                   F::InterpolateFuncOptions()
                                       .size(std::vector<int64_t>{d->height, d->width})
                                       .mode(torch::kNearest))[0];
        auto in = lens_blur(wall.contiguous(), d->radius[0].contiguous(), d->blur);
        sharp = wall.unsqueeze(0).expand({d->frames, 3, d->height, d->width}).contiguous();
        d->input = ((in * 255.0).round() / 255.0).unsqueeze(0).expand_as(sharp).contiguous();
    }
    d->static_camera = true;
    auto fit = [&, &d = d, &sharp = sharp](bool path) {
        FitOptions o;
        o.preset = "fast";
        o.iters = 400;
        o.batch = 2;  // the same frames a step with and without: the path is what is compared
        o.settings.set("fast.deblur_path", path ? "true" : "false");
        FitEngine e(std::make_shared<FitData>(*d), o);
        const bool has = e.model().state().count("bg_deblur") > 0;
        CHECK(has == path);
        CHECK(e.batch() == 2);
        if (path) {
            REQUIRE(e.model_notes().size() == 1);
            CHECK(e.model_notes()[0].find("median sharpest radius 4.0 px") != std::string::npos);
        }
        while (!e.done()) e.step();
        std::vector<torch::Tensor> out;
        for (int t = 0; t < d->frames; ++t) out.push_back(e.render_frame(t).sharp[0]);
        return psnr_of(torch::stack(out).clamp(0, 1), sharp);
    };
    const double off = fit(false), on = fit(true);
    MESSAGE("400 steps, sharp PSNR: input " << psnr_of(d->input, sharp) << " dB, texels alone "
                                            << off << ", with the path " << on);
    CHECK(on > off + 1.0);
    {
        // Left to the model, a fit with the path takes 4 frames a step and says so; without (the
        // default), 2.
        FitOptions o;
        o.preset = "fast";
        o.iters = 1;
        o.settings.set("fast.deblur_path", "true");
        FitEngine with(std::make_shared<FitData>(*d), o);
        CHECK(with.batch() == 4);
        REQUIRE(with.model_notes().size() == 2);
        CHECK(with.model_notes()[1].find("4 frames a step") != std::string::npos);
        o.settings.set("fast.deblur_path", "false");
        FitEngine without(std::make_shared<FitData>(*d), o);
        CHECK(without.batch() == 2);
        CHECK(without.model_notes().empty());
    }

    FastModelOptions o;
    o.align_rounds = 0;
    o.deblur_path = true;
    FastModel m(*d, o);
    auto s = m.state();
    REQUIRE(s.count("bg_deblur"));
    {
        // The path adds detail only: a constant through it leaves the atlas as it was.
        torch::NoGradGuard g;
        auto before = m.atlas_bg();
        s.at("bg_deblur").fill_(0.25);
        CHECK((m.atlas_bg() - before).abs().max().item<double>() < 1e-4);
    }
    // A checkpoint of an earlier build has no path: its texels hold the whole atlas.
    std::map<std::string, torch::Tensor> old;
    for (auto& [k, v] : s)
        if (k != "bg_deblur") old[k] = v.detach().clone();
    FastModel n(*d, o);
    n.load_state(old);
    CHECK(n.state().at("bg_deblur").abs().max().item<double>() == 0.0);
    // A blur under the threshold gets no path.
    auto [sharp_d, unused] = pan_over_detail(3, 0.0, 1.0);
    FastModel few(*sharp_d, o);
    CHECK(few.state().count("bg_deblur") == 0);
    CHECK(few.notes.at(0).find("no deblurring path") != std::string::npos);
}

TEST_CASE("alignment on a proxy corrects a frame's drift as at full size") {
    // A smooth texture panned 2 px a frame; frame 2's homography is off by (1.5, −1) px. ECC
    // (refine_alignment) on a half-size proxy must pull it back as ECC at full size does.
    namespace F = torch::nn::functional;
    const int64_t T = 4, H = 64, W = 96, M = 16;
    torch::manual_seed(5);
    auto tex = F::interpolate(torch::rand({1, 3, (H + 2 * M) / 4, (W + 2 * M) / 4}),
                              F::InterpolateFuncOptions()
                                  .size(std::vector<int64_t>{H + 2 * M, W + 2 * M})
                                  .mode(torch::kBicubic)
                                  .align_corners(false))
                   .clamp(0.02, 1);
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->blur.kernel = BlurKernel::Pillbox;
    std::vector<torch::Tensor> in, hs;
    for (int64_t t = 0; t < T; ++t) {
        auto f = tex[0].narrow(1, M, H).narrow(2, M + 2 * t, W).contiguous();
        in.push_back(lens_blur(f, torch::full({H, W}, 1.0f), d->blur));
        hs.push_back(translation(2.0 * t + (t == 2 ? 1.5 : 0.0), t == 2 ? -1.0 : 0.0));
    }
    d->input = torch::stack(in);
    d->radius = torch::full({T, H, W}, 1.0f);
    d->to_ref = torch::stack(hs).to(torch::kFloat64);
    d->static_camera = false;
    auto frame2 = [&](int rounds, int width) {
        FastModelOptions o;
        o.align_rounds = rounds;
        o.align_width = width;
        FastModel m(*d, o);
        torch::NoGradGuard g;
        return psnr_of(m.render({2}).sharp, d->input.narrow(0, 2, 1));
    };
    const double none = frame2(0, 0), full = frame2(2, 0), proxy = frame2(2, W / 2);
    MESSAGE("frame 2 rendered from the fused atlas: no alignment "
            << none << " dB, ECC at full "
            << "size " << full << " dB, on a half-size proxy " << proxy << " dB");
    CHECK(full > none + 3.0);
    CHECK(proxy > none + 3.0);
    CHECK(proxy > full - 1.5);
}

TEST_CASE("TV weights fused on a proxy follow those fused at full size") {
    // The per-texel TV factor (tv_radius_factor) of frames wider than align_width is fused on
    // the proxy and upsampled: the radius maps are smooth, so the prior changes little.
    auto [d, sharp] = pan_over_detail(4, 1.0, 1.0);
    const int64_t T = d->frames, H = d->height, W = d->width;
    auto ramp = (torch::arange(W, torch::kFloat32) / double(W - 1) * 2.5 + 0.5)
                    .view({1, 1, W})
                    .expand({T, H, W})
                    .contiguous();
    d->radius = ramp;  // 0.5 → 3 px across the frame: factor clamp(2r, 1, 4) varies
    auto tv_of = [&](int width) {
        FastModelOptions o;
        o.align_rounds = 0;
        o.align_width = width;
        FastModel m(*d, o);
        LossTerms terms;
        const std::vector<int64_t> frames{0, 1};
        m.priors(m.render(frames), frames, 100, terms);
        return terms.at("tv");
    };
    const double full = tv_of(0), same = tv_of(int(W)), proxy = tv_of(int(W / 2));
    MESSAGE("TV prior: full size " << full << ", on a half-size proxy " << proxy);
    CHECK(same == full);  // frames no wider than align_width: the full-size path
    CHECK(proxy != full);
    CHECK(std::fabs(proxy - full) < 0.05 * full);
}

TEST_CASE("renders outside training keep the composed atlas until an edit changes it") {
    // An export or playback composes each atlas once; an imported or painted atlas (set_atlas,
    // in place) must reach the next render.
    const int64_t T = 3, H = 24, W = 32;
    torch::manual_seed(8);
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->blur.kernel = BlurKernel::Pillbox;
    d->input = torch::rand({T, 3, H, W});
    d->radius = torch::full({T, H, W}, 0.1f);
    d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).clone();
    d->static_camera = true;
    FastModelOptions o;
    o.align_rounds = 0;
    FastModel m(*d, o);
    torch::NoGradGuard g;
    const auto first = m.render({0}).sharp.clone(), again = m.render({1, 0}).sharp;
    CHECK(torch::equal(first, again.narrow(0, 1, 1)));
    const auto atlas = m.atlas_bg();
    m.set_atlas_bg(torch::full_like(atlas, 0.25f));
    const auto edited = m.render({0}).sharp;
    CHECK((edited - 0.25f).abs().max().item<float>() < 1e-4f);
    m.set_atlas_bg(atlas);
    CHECK((m.render({0}).sharp - first).abs().max().item<float>() < 1e-5f);
}

TEST_CASE("an affine or projective alignment corrects a frame's zoom, on a proxy as at full size") {
    // The pan of the test above, frame 2's homography off by a 3 % zoom about the frame's
    // centre (a chained dolly's drift): a shift cannot take it, fast.align_motion=affine does.
    namespace F = torch::nn::functional;
    const int64_t T = 4, H = 64, W = 96, M = 16;
    torch::manual_seed(5);
    auto tex = F::interpolate(torch::rand({1, 3, (H + 2 * M) / 4, (W + 2 * M) / 4}),
                              F::InterpolateFuncOptions()
                                  .size(std::vector<int64_t>{H + 2 * M, W + 2 * M})
                                  .mode(torch::kBicubic)
                                  .align_corners(false))
                   .clamp(0.02, 1);
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->blur.kernel = BlurKernel::Pillbox;
    auto zoom = torch::eye(3, torch::kFloat64);
    const double s = 1.03, cx = 0.5 * (W - 1), cy = 0.5 * (H - 1);
    zoom[0][0] = zoom[1][1] = s;
    zoom[0][2] = cx * (1 - s), zoom[1][2] = cy * (1 - s);
    std::vector<torch::Tensor> in, hs;
    for (int64_t t = 0; t < T; ++t) {
        auto f = tex[0].narrow(1, M, H).narrow(2, M + 2 * t, W).contiguous();
        in.push_back(lens_blur(f, torch::full({H, W}, 1.0f), d->blur));
        auto h = translation(2.0 * t, 0.0).to(torch::kFloat64);
        hs.push_back(t == 2 ? torch::matmul(h, zoom) : h);
    }
    d->input = torch::stack(in);
    d->radius = torch::full({T, H, W}, 1.0f);
    d->to_ref = torch::stack(hs);
    d->static_camera = false;
    auto frame2 = [&](const char* motion, int width) {
        FastModelOptions o;
        o.align_motion = motion;
        o.align_width = width;
        FastModel m(*d, o);
        torch::NoGradGuard g;
        return psnr_of(m.render({2}).sharp, d->input.narrow(0, 2, 1));
    };
    const double shift = frame2("shift", 0), full = frame2("affine", 0),
                 proxy = frame2("affine", W / 2), hom = frame2("homography", W / 2);
    MESSAGE("frame 2 rendered from the fused atlas: a shift "
            << shift << " dB, affine at full "
            << "size " << full << " dB, on a half-size proxy " << proxy
            << " dB, a homography there " << hom << " dB");
    CHECK(full > shift + 3.0);
    CHECK(proxy > shift + 3.0);
    CHECK(proxy > full - 3.0);  // the proxy reads a coarser texture
    CHECK(hom > shift + 3.0);
}
