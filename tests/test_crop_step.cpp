// The fit's crop step (docs/method.md, Crops): crops cover every pixel equally often and are the
// same for the same seed; the fast model renders a window as the padded frame holds it (values
// and gradients); a crop fit resumes to the uninterrupted result; and a crop fit of a small
// synth clip comes within 0.3 dB of the whole-frame fit.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

#include "fit/crops.h"
#include "fit/fit_engine.h"
#include "fit/fit_setup.h"
#include "fit/lazy_adam.h"
#include "io/clip.h"
#include "io/tensor_image.h"
#include "metrics/metrics.h"
#include "project/project.h"
#include "util/error.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("crops: inside the frame, every pixel equally often, the same for the same seed") {
    const int64_t W = 640, H = 360;
    // Each crop's mean loss gives its pixels 1/(w·h) each: summed over many steps, a pixel's
    // share is what the whole frame's mean gives it (1/(W·H) a frame) when coverage is even.
    auto share = torch::zeros({H, W}, torch::kFloat64);
    int64_t crops = 0;
    for (int64_t step = 0; step < 3000; ++step) {
        const Crops c = draw_crops(W, H, 256, 7, step, 4);
        REQUIRE(c.x.size() == 4);
        CHECK(!c.whole);
        CHECK(c.w <= 320);  // ⌊640/256⌋ = 2 or 3 tiles across, 1 or 2 down
        CHECK(c.h <= 360);
        for (size_t b = 0; b < 4; ++b) {
            REQUIRE(c.x[b] >= 0);
            REQUIRE(c.y[b] >= 0);
            REQUIRE(c.x[b] + c.w <= W);
            REQUIRE(c.y[b] + c.h <= H);
            share.narrow(0, c.y[b], c.h).narrow(1, c.x[b], c.w) += 1.0 / double(c.w * c.h);
            ++crops;
        }
    }
    share *= double(W * H) / double(crops);  // 1 where a pixel weighs as in the whole frame
    // Tiles of ⌈L/n⌉ px overlap by under n px: those few columns and rows weigh up to twice.
    auto sorted = std::get<0>(share.flatten().sort());
    auto q = [&](double p) {
        return sorted[int64_t(p * double(sorted.numel() - 1))].item<double>();
    };
    MESSAGE("crop share of each pixel against the whole frame's: 1% "
            << q(0.01) << ", 99% " << q(0.99) << ", max " << q(1.0));
    CHECK(q(0.0) > 0.85);
    CHECK(q(0.01) > 0.9);
    CHECK(q(0.99) < 1.1);
    CHECK(q(1.0) < 2.2);

    const Crops a = draw_crops(W, H, 256, 7, 42, 4), b = draw_crops(W, H, 256, 7, 42, 4);
    CHECK(a.x == b.x);
    CHECK(a.y == b.y);
    CHECK(a.w == b.w);
    bool differs = false;
    for (int64_t s = 0; s < 20; ++s) differs |= draw_crops(W, H, 256, 8, s, 4).x != a.x;
    CHECK(differs);
    // Frames no larger than the crop, or crop_px 0, keep the whole frame.
    CHECK(draw_crops(320, 180, 320, 1, 3, 2).whole);
    CHECK(draw_crops(W, H, 0, 1, 3, 2).whole);
    const Crops one_axis = draw_crops(640, 180, 320, 1, 5, 2);
    CHECK(one_axis.h == 180);

    // The scored regions (a crop and the 10 px its blur reaches) and the windows (8 px more,
    // at most 8 px past the frame) keep one size and hold what they grow, shifted inward at
    // the frame's edges.
    for (int64_t step = 0; step < 50; ++step) {
        const Crops c = draw_crops(W, H, 256, 3, step, 4);
        const Crops s = grow_crops(c, W, H, 10);
        const Windows w = crop_windows(s, W, H, 8, 8);
        CHECK(s.w == std::min<int64_t>(c.w + 20, W));
        CHECK(w.w == std::min<int64_t>(s.w + 16, W + 16));
        for (size_t b = 0; b < 4; ++b) {
            CHECK(s.x[b] >= 0);
            CHECK(s.x[b] + s.w <= W);
            CHECK(s.x[b] <= std::max<int64_t>(c.x[b] - 10, 0));
            CHECK(s.x[b] + s.w >= std::min<int64_t>(c.x[b] + c.w + 10, W));
            CHECK(w.x0[b] >= -8);
            CHECK(w.y0[b] + w.h <= H + 8);
            CHECK(w.x0[b] <= std::max<int64_t>(s.x[b] - 8, -8));
            CHECK(w.y0[b] <= std::max<int64_t>(s.y[b] - 8, -8));
        }
    }
}

TEST_CASE("lazy Adam: Adam where every entry has a gradient; still where none has") {
    torch::manual_seed(5);
    auto a = torch::randn({4, 6}).requires_grad_(true), b = a.detach().clone().requires_grad_(true);
    torch::optim::Adam plain({a}, torch::optim::AdamOptions(0.01));
    LazyAdam lazy({b}, torch::optim::AdamOptions(0.01));
    auto mask = torch::ones({4, 6});
    mask[1].zero_();  // row 1 gets no gradient from step 3 on
    auto frozen = torch::Tensor();
    for (int step = 0; step < 6; ++step) {
        auto w = torch::randn({4, 6});
        if (step >= 3) w = w * mask;
        if (step == 3) frozen = b.detach()[1].clone();
        plain.zero_grad();
        lazy.zero_grad();
        (a * w).sum().backward();
        (b * w).sum().backward();
        plain.step();
        lazy.step();
        if (step < 3) CHECK((a - b).abs().max().item<double>() < 1e-6);
    }
    CHECK((b.detach()[1] - frozen).abs().max().item<double>() == 0.0);  // plain Adam drifts on
    CHECK((a.detach()[1] - frozen).abs().max().item<double>() > 1e-4);
}

namespace {

// The tiny two-layer data on a moving camera, so that the background's residual warp is
// learned too, blurred by 1.5 px (a 2 px margin).
std::shared_ptr<FitData> moving_two_layer_data() {
    auto d = tiny_two_layer_data(4);
    d->static_camera = false;
    d->radius.fill_(1.5);
    for (int64_t t = 0; t < d->frames; ++t) {
        d->to_ref[t][0][2] = 0.7 * double(t);
        d->to_ref[t][1][2] = -0.4 * double(t);
    }
    return d;
}

FitOptions quick(int64_t iters, int64_t crop_px) {
    FitOptions o;
    o.iters = iters;
    o.crop_px = crop_px;
    o.batch = 2;
    return o;
}

}  // namespace

TEST_CASE("fast model: a window renders, and takes gradients, as the padded frame does there") {
    auto o = quick(1, 0);
    // Each frame's box of the atlases, not the whole atlas composed once (which these small
    // atlases would take at the default share).
    o.settings.set("fast.window_share", "1e9");
    FitEngine e(moving_two_layer_data(), o);
    FitModel& m = e.model();
    const int64_t P = m.max_pad();
    REQUIRE(P > 0);
    {  // residual warps and mattes that are not zero, so that their windows are read too
        torch::NoGradGuard g;
        torch::manual_seed(2);
        auto s = m.state();
        for (const char* k : {"bg_warp", "fg_warp"}) s.at(k).copy_(torch::randn_like(s.at(k)));
        s.at("alpha_logit").copy_(2.0 * torch::randn_like(s.at("alpha_logit")));
        // Every level holds texels (a window composes the coarse ones over its box), and frames
        // 1 and 3 see the subject 3.5 and 2.2 times smaller than its atlas (their windows are
        // prefiltered, 3 and 1 texels' reach).
        for (auto& [k, v] : s)
            if (k.find("_level") != std::string::npos) v.add_(0.2 * torch::randn_like(v));
        s.at("fg_to_atlas")[1].narrow(0, 0, 2).narrow(1, 0, 2).mul_(3.5);
        s.at("fg_to_atlas")[3].narrow(0, 0, 2).narrow(1, 0, 2).mul_(2.2);
    }
    const std::vector<int64_t> frames{1, 3, 0};
    // Windows at the top-left margin, inside, and at the bottom-right margin of the 40x24 frame.
    const std::vector<int64_t> x0{-P, 9, 40 + P - 17}, y0{-P, 5, 24 + P - 11};
    const int64_t h = 11, w = 17;
    auto params = [&] {
        std::vector<torch::Tensor> p;
        for (auto& g : m.param_groups())
            for (auto& t : g.params) p.push_back(t);
        return p;
    };
    auto grads = [&](const torch::Tensor& loss) {
        for (auto& t : params())
            if (t.grad().defined()) t.grad().zero_();
        loss.backward();
        std::vector<torch::Tensor> g;
        for (auto& t : params())
            g.push_back(t.grad().defined() ? t.grad().clone() : torch::Tensor());
        return g;
    };
    torch::manual_seed(3);
    auto weight = torch::randn({3, 4, h, w});  // a loss over the windows' sharp and alpha
    auto loss_of = [&](const Layers& L) {
        return (torch::cat({L.sharp, L.alpha}, 1) * weight).sum();
    };
    Layers win = m.render_window(frames, x0, y0, h, w);
    Layers pad = m.render_padded(frames, P);
    std::vector<torch::Tensor> cut_sharp, cut_alpha, cut_uv;
    for (size_t b = 0; b < frames.size(); ++b) {
        cut_sharp.push_back(pad.sharp[b].narrow(1, y0[b] + P, h).narrow(2, x0[b] + P, w));
        cut_alpha.push_back(pad.alpha[b].narrow(1, y0[b] + P, h).narrow(2, x0[b] + P, w));
        cut_uv.push_back(pad.uv_fg[b].narrow(0, y0[b] + P, h).narrow(1, x0[b] + P, w));
    }
    Layers cut;
    cut.sharp = torch::stack(cut_sharp);
    cut.alpha = torch::stack(cut_alpha);
    CHECK((win.sharp - cut.sharp).abs().max().item<double>() < 1e-5);
    CHECK((win.alpha - cut.alpha).abs().max().item<double>() < 1e-5);
    CHECK((win.uv_fg - torch::stack(cut_uv)).abs().max().item<double>() < 1e-6);
    CHECK(win.x0 == x0);
    const auto gw = grads(loss_of(win));
    pad = m.render_padded(frames, P);
    cut_sharp.clear();
    cut_alpha.clear();
    for (size_t b = 0; b < frames.size(); ++b) {
        cut_sharp.push_back(pad.sharp[b].narrow(1, y0[b] + P, h).narrow(2, x0[b] + P, w));
        cut_alpha.push_back(pad.alpha[b].narrow(1, y0[b] + P, h).narrow(2, x0[b] + P, w));
    }
    cut.sharp = torch::stack(cut_sharp);
    cut.alpha = torch::stack(cut_alpha);
    const auto gp = grads(loss_of(cut));
    REQUIRE(gw.size() == gp.size());
    double worst = 0;
    for (size_t i = 0; i < gw.size(); ++i) {
        REQUIRE(gw[i].defined() == gp[i].defined());
        if (!gw[i].defined()) continue;
        const double scale = std::max(gp[i].abs().max().item<double>(), 1e-12);
        worst = std::max(worst, (gw[i] - gp[i]).abs().max().item<double>() / scale);
    }
    MESSAGE("window against padded frame: worst relative gradient difference " << worst);
    CHECK(worst < 1e-4);
    // The base class cuts the same windows out of render_padded.
    Layers base = m.FitModel::render_window(frames, x0, y0, h, w);
    CHECK((base.sharp - win.sharp).abs().max().item<double>() < 1e-5);
    // TV over the windows' boxes from the render's own windows, then (none kept: priors()
    // consumed them) from the atlas composed whole.
    win = m.render_window(frames, x0, y0, h, w);
    LossTerms from_windows, from_whole;
    m.priors(win, frames, 0, from_windows);
    m.priors(win, frames, 0, from_whole);
    CHECK(from_windows.at("tv") > 0);
    CHECK(from_windows.at("tv") == doctest::Approx(from_whole.at("tv")).epsilon(1e-5));
    CHECK_THROWS_WITH_AS(m.render_window({0}, {-P - 1}, {0}, h, w),
                         doctest::Contains("reaches past"), Error);
}

TEST_CASE("crop step: the same seed gives the same fit, and a resumed fit the uninterrupted one") {
    auto run = [](int64_t stop_at, const fs::path& ckpt_in, const fs::path& ckpt_out) {
        FitEngine e(moving_two_layer_data(), quick(12, 32));
        bool noted = false;
        for (const auto& n : e.model_notes()) noted |= n.find("crops") != std::string::npos;
        CHECK(noted);
        if (!ckpt_in.empty()) e.load_checkpoint(ckpt_in);
        while (!e.done() && e.snapshot().step < stop_at) e.step();
        if (!ckpt_out.empty()) e.save_checkpoint(ckpt_out);
        return e.render_frame(2).sharp;
    };
    const fs::path dir = scratch_dir("crop_resume");
    const auto a = run(12, {}, {}), b = run(12, {}, {});
    CHECK((a - b).abs().max().item<double>() == 0.0);
    run(5, {}, dir / "ck");
    const auto resumed = run(12, dir / "ck", {});
    CHECK((resumed - a).abs().max().item<double>() < 1e-6);
    CHECK_THROWS_WITH_AS(FitEngine(moving_two_layer_data(), quick(1, 16)),
                         doctest::Contains("fit.crop_px"), Error);
}

namespace {

// Mean sharp PSNR (sRGB 8-bit, as the benches score) of the model's frames against `gt`.
double sharp_psnr(FitEngine& e, const std::vector<Image>& gt) {
    std::vector<Image> out;
    for (int t = 0; t < int(gt.size()); ++t)
        out.push_back(tensor_to_image(e.render_frame(t).sharp[0].clamp_min(0)));
    return mean_psnr(out, gt);
}

}  // namespace

TEST_CASE(
    "crop step: a crop fit of a small synth clip comes within 0.3 dB of the whole-frame fit") {
    // Synth rack at 272x96 (8 frames, true radius): a moving camera, two layers. Crops of
    // fit.crop_px 120 are 136 or 91 px across and the frame's 96 px down, so MS-SSIM keeps the
    // whole frame's 4 scales and the comparison is of the crop step alone. They see 0.42 of a
    // frame's pixels a step: the crop fit takes as many steps as see the same pixels.
    TinyClip c = make_tiny("crop_fit", "rack", "272x96");
    const Project project = Project::load(c.project);
    FitSetupOptions setup;
    setup.coc_path = (c.clip / "coc_%04d.exr").string();
    PrepareLog log;
    const auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((c.clip / "input_%04d.png").string());
    const int64_t W = 272, H = 96, crop = 120, whole_steps = 80;
    auto fit = [&](int64_t crop_px, int64_t steps) {
        FitOptions o;
        o.iters = steps;
        o.crop_px = crop_px;
        FitEngine e(build_fit_data(project, setup, log), o);
        while (!e.done()) e.step();
        return sharp_psnr(e, gt);
    };
    double share = 0;  // of a frame's pixels a crop step trains, over the steps it takes
    for (int64_t s = 0; s < 1000; ++s) {
        const Crops k = draw_crops(W, H, crop, 1, s, 1);
        share += double(k.w * k.h) / double(W * H) / 1000.0;
    }
    const int64_t crop_steps = std::llround(double(whole_steps) / share);
    const double whole = fit(0, whole_steps), cropped = fit(crop, crop_steps);
    const double in = mean_psnr(input, gt);
    MESSAGE("synth rack 272x96x8, true radius: input "
            << in << " dB; whole frames " << whole << " dB in " << whole_steps << " steps; crops "
            << cropped << " dB in " << crop_steps << " steps (" << share
            << " of a frame's pixels a step)");
    CHECK(whole > in + 3.0);
    CHECK(cropped > whole - 0.3);
}
