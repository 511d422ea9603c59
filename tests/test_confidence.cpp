// Never worse than the shot: the confidence maps (fit/confidence.h) and the fallback they drive.
#include <torch/torch.h>

#include <doctest/doctest.h>

#include <cstdio>
#include <limits>
#include <vector>

#include "fit/confidence.h"
#include "fit/fit_engine.h"
#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "ops/morphology.h"
#include "test_util.h"

using namespace refocus;

namespace {

double px_at(const torch::Tensor& m, int y, int x) {
    return m[0][0][y][x].item<double>();
}

// Frame s's radius map [H,W]: frame 3 sees the left half at 0.5 px, everything else is at 6 px.
torch::Tensor left_sharp_in_frame3(int s, int H, int W) {
    auto r = torch::full({H, W}, 6.0);
    if (s == 3) r.narrow(1, 0, W / 2).fill_(0.5);
    return r;
}

}  // namespace

TEST_CASE("an isolated bad frame falls back fully and its neighbours fade toward it") {
    const int T = 11, H = 8, W = 8;
    auto to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    auto u_of = [&](int s) {
        return s == 5 ? torch::ones({1, 1, H, W}) : torch::zeros({1, 1, H, W});
    };
    std::vector<double> h;
    for (int t = 0; t < T; ++t)
        h.push_back(px_at(temporal_unexplained(t, T, 2, to_ref, true, u_of), 4, 4));
    CHECK(h[5] == doctest::Approx(1.0));
    for (int t : {3, 4, 6, 7}) CHECK(h[t] == doctest::Approx(0.2));
    for (int t : {0, 1, 2, 8, 9, 10}) CHECK(h[t] == doctest::Approx(0.0));
    // Near the clip's ends the mean is over the frames there are.
    auto u0 = [&](int s) { return torch::full({1, 1, H, W}, s == 0 ? 1.0 : 0.0); };
    CHECK(px_at(temporal_unexplained(1, T, 2, to_ref, true, u0), 0, 0) == doctest::Approx(0.25));
    // A frame not measured yet gives nothing; window 0 is the frame's own share.
    auto none = [&](int) { return torch::Tensor(); };
    CHECK_FALSE(temporal_unexplained(3, T, 2, to_ref, true, none).defined());
    CHECK(px_at(temporal_unexplained(4, T, 0, to_ref, true, u_of), 0, 0) == 0.0);
}

TEST_CASE("a frame's map is drawn in another frame's pixels through the homographies") {
    const int H = 10, W = 16;
    // Frame 1 sees the reference shifted: its pixel x is the reference's x + 3.
    auto to_ref = torch::eye(3, torch::kFloat64).repeat({2, 1, 1});
    to_ref[1][0][2] = 3.0;
    auto m1 = torch::zeros({1, 1, H, W});
    m1[0][0][4][8] = 1.0;  // reference point (11, 4)
    auto in0 = warp_frame_map(m1, to_ref, 1, 0);
    CHECK(px_at(in0, 4, 11) == doctest::Approx(1.0));
    CHECK(px_at(in0, 4, 8) == doctest::Approx(0.0));
}

TEST_CASE("the need to fix: zero where no blur reaches, one within a blurred region's spill") {
    const int H = 40, W = 40;
    auto r = torch::zeros({H, W});
    r.narrow(0, 15, 10).narrow(1, 15, 10).fill_(6.0);  // a blurred square, 6 px
    // The fused loop against the reference, to the last bit: smooth maps, noise, an outlier,
    // one row or column.
    torch::manual_seed(3);
    for (const auto& m : {torch::rand({37, 53}) * 6.0, torch::rand({1, 1, 20, 31}) * 0.4,
                          torch::zeros({16, 16}).index_put_({7, 9}, 12.5), torch::rand({1, 40}) * 3,
                          torch::rand({40, 1}) * 3, torch::zeros({9, 9})}) {
        CHECK(torch::equal(blur_reach(m), blur_reach_reference(m)));
    }
    auto need = blur_need(blur_reach(r), 0.5);
    CHECK(px_at(need, 20, 20) == doctest::Approx(1.0));
    CHECK(px_at(need, 20, 28) == doctest::Approx(1.0));  // 4 px outside: its blur spills there
    CHECK(px_at(need, 20, 38) == doctest::Approx(0.0));  // 14 px outside: untouched
    CHECK(px_at(need, 2, 2) == doctest::Approx(0.0));
    CHECK(blur_need(blur_reach(r), 0).min().item<double>() == 1.0);  // off
}

TEST_CASE("the sharpest the clip saw a pixel, and how far that lets the model restore it") {
    const int T = 6, H = 12, W = 20;
    auto radius_of = [&](int s) { return left_sharp_in_frame3(s, H, W); };
    auto still = torch::eye(3, torch::kFloat64).repeat({T, 1, 1});
    for (bool static_camera : {true, false}) {
        auto best = sharpest_seen(0, T, 32, still, static_camera, 30.0, radius_of);
        CHECK(px_at(best, 6, 2) == doctest::Approx(0.5));
        CHECK(px_at(best, 6, 17) == doctest::Approx(6.0));
    }
    auto tau = seen_trust(sharpest_seen(0, T, 32, still, true, 30.0, radius_of), 2.0);
    CHECK(px_at(tau, 6, 2) == doctest::Approx(1.0));   // restored: frame 3 recorded it
    CHECK(px_at(tau, 6, 17) == doctest::Approx(0.0));  // no frame did: the shot
    CHECK(px_at(tau, 6, 10) > 0.2);                    // feathered across the seam
    CHECK(px_at(tau, 6, 10) < 0.8);
    CHECK(seen_trust(torch::full({1, 1, H, W}, 9.0), 0).min().item<double>() == 1.0);  // off
    // A pan: frame 3 sees the reference shifted by 8 px; its sharp half covers frame 0's columns
    // 8..17, and frame 0's columns 0..7 were not in frame 3's view at all.
    auto pan = still.clone();
    pan[3][0][2] = 8.0;  // frame 3's x is the reference's x + 8... (frame → reference: x + 8)
    auto best = sharpest_seen(0, T, 32, pan, false, 30.0, radius_of);
    CHECK(px_at(best, 6, 12) == doctest::Approx(0.5));
    CHECK(px_at(best, 6, 3) == doctest::Approx(6.0));  // the other frames saw it at 6 px
    // With a stride the spread still reaches every part of the clip.
    CHECK(px_at(sharpest_seen(0, T, 2, still, true, 30.0, radius_of), 6, 2) ==
          doctest::Approx(0.5));
}

TEST_CASE("two layers: a sharp subject passing over a blurred wall is no sharp view of the wall") {
    // A locked-off shot of a subject walking across a wall blurred 6 px in every frame; the
    // subject is sharp in frames 0-2 and blurred 5 px from frame 3 on. The visible surface is
    // sharp wherever the subject has been in its first frames, the wall never.
    const int64_t T = 6, H = 36, W = 64, S = 12;
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    torch::manual_seed(1);
    d->input = torch::rand({T, 3, H, W});
    d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).clone();
    d->static_camera = true;
    d->has_subject = true;
    d->mask = torch::zeros({T, 1, H, W});
    d->radius = torch::full({T, H, W}, 6.0f);
    auto x_of = [&](int64_t t) { return 4 + 9 * t; };  // the subject's left edge in frame t
    auto subject_r = [](int64_t t) { return t < 3 ? 0.3f : 5.0f; };
    for (int64_t t = 0; t < T; ++t) {
        d->mask[t].narrow(1, 12, S).narrow(2, x_of(t), S).fill_(1.0f);
        d->radius[t].narrow(0, 12, S).narrow(1, x_of(t), S).fill_(subject_r(t));
    }
    FitOptions o;
    o.preset = "fast";
    o.iters = 1;
    FitEngine e(d, o);  // splits the radius by layer (split_radius_by_layer)
    const int64_t last = T - 1, y = 12 + S / 2;
    auto best = e.sharpest_seen_map(last);
    auto tau = e.seen_trust_map(last);
    auto w = e.model_weight(last);
    REQUIRE(best.defined());
    REQUIRE(tau.defined());
    REQUIRE(w.defined());
    // Frame 0's subject stood at columns 4..15: the wall there was never seen sharp, and the
    // plate keeps the shot.
    CHECK(px_at(best, y, 9) > 5.0);
    CHECK(px_at(tau, y, 9) < 0.05);
    CHECK(px_at(w, y, 9) < 0.05);
    // The subject, blurred now, was seen sharp in its first frames (along its own track, not
    // at these pixels): the model carries that view here.
    const int64_t at = x_of(last) + S / 2;
    CHECK(px_at(best, y, at) < 1.0);
    CHECK(px_at(tau, y, at) > 0.95);
    CHECK(px_at(w, y, at) > 0.95);
    // Far from any of its positions the wall reads its own 6 px.
    CHECK(px_at(best, 2, 60) == doctest::Approx(6.0).epsilon(0.01));
    // Frame 1: the subject is sharp in front of the blurred wall. The wall's blur does not
    // spill over a subject in front of it: the shot is its best view, and is kept.
    auto w1 = e.model_weight(1);
    const double at1 = px_at(w1.defined() ? w1 : torch::ones({1, 1, H, W}), y, x_of(1) + S / 2);
    CHECK(at1 < 0.05);
}

TEST_CASE("a sharper view: the model replaces a pixel only where another frame saw it sharper") {
    const int T = 6, H = 12, W = 40;
    auto radius_of = [&](int s) { return left_sharp_in_frame3(s, H, W); };
    auto still = torch::eye(3, torch::kFloat64).repeat({T, 1, 1});
    auto best = sharpest_seen(0, T, 32, still, true, 30.0, radius_of);
    // Frame 0: frame 3 saw the left half 5.5 px sharper; nobody saw the right half sharper.
    auto g0 = sharper_view(blur_reach(radius_of(0)), best, 1.0);
    CHECK(px_at(g0, 6, 2) == doctest::Approx(1.0));
    CHECK(px_at(g0, 6, 37) == doctest::Approx(0.0));
    // Frame 3 is its own sharpest view everywhere, but the blur of its right half spills up to
    // 6 px into the left half, which other frames saw no sharper: the model is kept there.
    auto g3 = sharper_view(blur_reach(radius_of(3)), best, 1.0);
    CHECK(px_at(g3, 6, 2) == doctest::Approx(0.0));
    CHECK(px_at(g3, 6, 18) > 0.3);  // the right half's blur spills 2 px away
    CHECK(px_at(g3, 6, 37) == doctest::Approx(0.0));
    CHECK(sharper_view(blur_reach(radius_of(0)), best, 0).min().item<double>() == 1.0);  // off
}

TEST_CASE(
    "where focus moved over a point, a small sharper view counts; where it never moved, not") {
    // Left half: a rack, focus passes over it (0.5 px in frame 3, 5 px elsewhere). Right half:
    // focus never moves, and the estimate wobbles by 1 px between frames (4 px, 3 px in frame 3).
    const int T = 6, H = 12, W = 40;
    auto radius_of = [&](int s) {
        auto r = torch::full({H, W}, 4.0);
        r.narrow(1, 0, W / 2).fill_(5.0);
        if (s == 3) {
            r.narrow(1, 0, W / 2).fill_(0.5);
            r.narrow(1, W / 2, W / 2).fill_(3.0);
        }
        if (s == 4) r.narrow(1, 0, W / 2).fill_(4.0);  // the rack on its way: 1 px sharper
        return r;
    };
    auto still = torch::eye(3, torch::kFloat64).repeat({T, 1, 1});
    for (bool static_camera : {true, false}) {
        auto seen = seen_radius(0, T, 32, still, static_camera, 30.0, radius_of);
        CHECK(px_at(seen.least, 6, 2) == doctest::Approx(0.5));
        CHECK(px_at(seen.most, 6, 2) == doctest::Approx(5.0));
        CHECK(px_at(seen.most - seen.least, 6, 37) == doctest::Approx(1.0));
        CHECK(px_at(seen.least, 6, 37) ==
              px_at(sharpest_seen(0, T, 32, still, static_camera, 30.0, radius_of), 6, 37));
    }
    auto seen = seen_radius(0, T, 32, still, true, 30.0, radius_of);
    const auto range = seen.most - seen.least;
    // Frame 4 sees the rack 1 px sharper than frame 0 did, and the static half 0 px; frame 0
    // sees the static half 1 px blurrier than frame 3: under 2 px, not a sharper view.
    auto g4 = sharper_view(blur_reach(radius_of(4)), seen.least, range, 2.0, 0.5, 2.5);
    CHECK(px_at(g4, 6, 2) == doctest::Approx(1.0));  // 3.5 px sharper in frame 3: the model
    auto g0 = sharper_view(blur_reach(radius_of(0)), seen.least, range, 2.0, 0.5, 2.5);
    CHECK(px_at(g0, 6, 37) == doctest::Approx(0.0));  // never moved: 1 px is the estimate's noise
    // Frame 0 of a clip whose rack reaches only 1.2 px sharper than it: kept at 2 px, taken
    // where focus moved.
    auto near = seen.least.clone();
    near.narrow(3, 0, W / 2).fill_(3.8);
    CHECK(px_at(sharper_view(blur_reach(radius_of(0)), near, range, 2.0, 0.5, 2.5), 6, 2) ==
          doctest::Approx(1.0));
    CHECK(px_at(sharper_view(blur_reach(radius_of(0)), near, torch::Tensor(), 2.0, 0.5, 2.5), 6,
                2) == doctest::Approx(0.0));  // no range: γ as before
    CHECK(px_at(sharper_view(blur_reach(radius_of(0)), near, range, 2.0, 0.5, 0), 6, 2) ==
          doctest::Approx(0.0));  // off
}

TEST_CASE("a layer's focus travel: a gentle rack counts as moved, the estimate's noise does not") {
    // A rack from 0.2 to 2.8 px over 8 frames on a wall of 40x30, plus ±1 px of noise that
    // changes from frame to frame: each pixel's own range mixes both, the frames' medians not.
    const int T = 8, H = 30, W = 40;
    torch::manual_seed(3);
    std::vector<torch::Tensor> rack, still;
    for (int s = 0; s < T; ++s) {
        auto noise = torch::rand({H, W}, torch::kFloat32) * 2.0 - 1.0;
        rack.push_back((0.2 + 2.6 * s / (T - 1.0) + noise).clamp_min(0));
        still.push_back((2.5 + noise).clamp_min(0));
    }
    const double moving = focus_travel(
        T, [&](int s) { return rack[s]; }, nullptr);
    const double fixed = focus_travel(
        T, [&](int s) { return still[s]; }, nullptr);
    CHECK(moving == doctest::Approx(2.6).epsilon(0.1));
    CHECK(fixed < 0.3);
    // A region that covers under 1 % of a frame does not count; one that does, does.
    auto region = [&](int s) {
        auto m = torch::zeros({H, W});
        if (s % 2) m.narrow(0, 0, 15).fill_(1);
        return m;
    };
    CHECK(focus_travel(
              T, [&](int s) { return rack[s]; }, region) ==
          doctest::Approx(2.6 * 6 / 7).epsilon(0.15));  // odd frames only: 1 to 7

    // The range 1.4 px (half the rack's travel) reads as a full move of 4 px, the same range on
    // the still wall stays 1.4; a long rack keeps the absolute test; off leaves it.
    auto range = torch::full({1, 1, 4, 4}, 1.4);
    CHECK(px_at(range_by_travel(range, moving, 4.0, 2.0), 1, 1) ==
          doctest::Approx(4.3).epsilon(0.1));
    CHECK(px_at(range_by_travel(range, fixed, 4.0, 2.0), 1, 1) == doctest::Approx(1.4));
    CHECK(px_at(range_by_travel(range, 9.0, 4.0, 2.0), 1, 1) == doctest::Approx(1.4));
    CHECK(px_at(range_by_travel(range, moving, 4.0, 0.0), 1, 1) == doctest::Approx(1.4));
    // Between 1.5 and 2 px of travel the threshold eases from 4 px to half the travel.
    const double mid = px_at(range_by_travel(range, 1.75, 4.0, 2.0), 1, 1);
    CHECK(mid > 1.4);
    CHECK(mid < 1.4 * 4.0 / 0.875);
}

TEST_CASE("the unexplained share: a region far above the frame's typical residual") {
    const int H = 48, W = 48;
    auto e = torch::full({1, 1, H, W}, 0.01);
    e[0][0].narrow(0, 16, 16).narrow(1, 16, 16).fill_(0.2);  // a 16 px region unexplained
    for (int y = 0; y < H; ++y) e[0][0][y][40] = 0.5;        // a 1-px band: an edge under parallax
    auto u = unexplained_share(e, 4.0, 0.04);
    CHECK(px_at(u, 24, 24) == doctest::Approx(1.0));
    CHECK(px_at(u, 24, 40) > 0.3);  // a thin band falls back too (not opened away)
    CHECK(px_at(u, 4, 4) == doctest::Approx(0.0));
    CHECK(px_at(u, 24, 6) == doctest::Approx(0.0));
    CHECK_FALSE(unexplained_share(torch::full({1, 1, 4, 4}, -1.0), 4, 0.04).defined());
}

TEST_CASE("the evidence rule: a residual the noise and the model's change explain is kept") {
    // σ = 4 levels: a right model leaves |e| ≈ 0.8·4/255 = 0.0125 everywhere. Left third: the
    // model restores little (D = 0.005) and misses by 0.05: wrong. Middle: it restores much
    // (D = 0.12) and misses by 0.05: within half of its change. Right: noise alone.
    const int H = 40, W = 120;
    auto e = torch::full({1, 1, H, W}, 0.0125);
    auto d = torch::full({1, 1, H, W}, 0.005);
    e.narrow(3, 0, 40).fill_(0.05);
    e.narrow(3, 40, 40).fill_(0.05);
    d.narrow(3, 40, 40).fill_(0.12);
    auto u = unexplained_share_evidence(e, d, 4.0, 0.5, 0.004);
    CHECK(px_at(u, 20, 10) == doctest::Approx(1.0));   // misses by more than it restores
    CHECK(px_at(u, 20, 60) == doctest::Approx(0.0));   // restores more than twice its miss
    CHECK(px_at(u, 20, 110) == doctest::Approx(0.0));  // the noise
    // The same noise read as 0 levels: the noise alone now passes the floor (0.004 + 0.0025).
    CHECK(px_at(unexplained_share_evidence(e, d, 0.0, 0.5, 0.004), 20, 110) > 0.9);
    // The median rule calls half of a frame unexplained by rank whatever the residual is.
    auto ramp = torch::linspace(0.004, 0.012, W).view({1, 1, 1, W}).expand({1, 1, H, W});
    CHECK(px_at(unexplained_share(ramp.contiguous(), 1.0, 0.001), 20, 110) > 0.1);
    CHECK(px_at(unexplained_share_evidence(ramp.contiguous(), d, 4.0, 0.5, 0.004), 20, 110) ==
          doctest::Approx(0.0));
    CHECK_FALSE(unexplained_share_evidence(torch::full({1, 1, 4, 4}, -1.0),
                                           torch::zeros({1, 1, 4, 4}), 4, 0.5, 0.004)
                    .defined());
}

TEST_CASE("a fit explains the clip where its residual over the noise is under the threshold") {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    CHECK(explained_trust(2.0, 0.0, 3.5) == doctest::Approx(1.0));
    CHECK(explained_trust(3.5, 0.0, 3.5) == doctest::Approx(1.0));
    CHECK(explained_trust(4.9, 0.0, 3.5) == doctest::Approx(0.0));
    const double mid = explained_trust(4.2, 0.0, 3.5);  // halfway through 3.5..4.9
    CHECK(mid == doctest::Approx(0.5));
    // σ 4 noise leaves 0.8·4 = 3.2 levels a right model cannot explain: 4.8 RMS is 3.58 over it.
    CHECK(explained_trust(4.8, 4.0, 3.5) > 0.95);
    CHECK(explained_trust(4.8, 0.0, 3.5) < 0.1);
    // A residual under the noise is no excess; never measured or off is no trust.
    CHECK(explained_trust(1.0, 4.0, 3.5) == doctest::Approx(1.0));
    CHECK(explained_trust(nan, 0.0, 3.5) == 0.0);
    CHECK(explained_trust(1.0, 0.0, 0.0) == 0.0);
    // The excess over the noise (κ's trusted floor reads it too): 5 levels over σ 5 (0.8σ = 4).
    CHECK(residual_excess(5.0, 5.0) == doctest::Approx(3.0));
    CHECK(residual_excess(2.0, 5.0) == 0.0);
}

TEST_CASE("the low-frequency lock: a colour shift is undone, fine detail is kept") {
    torch::manual_seed(3);
    const int H = 40, W = 48;
    auto input = torch::rand({1, 3, H, W}) * 0.5 + 0.25;
    // A model frame with the input's content, every channel shifted, plus a 1-px checker: the
    // detail a deblur adds.
    auto yy = torch::arange(H).view({H, 1}), xx = torch::arange(W).view({1, W});
    auto checker = (((yy + xx) % 2) * 2 - 1).to(torch::kFloat32).view({1, 1, H, W}) * 0.1;
    auto shift = torch::tensor({0.04f, -0.03f, 0.02f}).view({1, 3, 1, 1});
    auto model = input + shift + checker;
    auto fixed = model + low_frequency_lock(model, input, 2.0);
    // Each channel's mean comes back to the input's (the 0.5 code-value target is ~0.002).
    auto mean_err = (fixed - input).mean({0, 2, 3}).abs().max().item<double>();
    CHECK(mean_err < 1e-3);
    // The checker (far above the lock's scale) stays: what is left of the change is it.
    auto kept =
        ((fixed - input) * checker).sum().item<double>() / (checker * checker).sum().item<double>();
    CHECK(kept > 0.95);
    // The Gaussian keeps a constant (edges replicated) and sums to one.
    auto c = torch::full({1, 1, 9, 9}, 0.3f);
    CHECK((gaussian_blur(c, 2.0) - 0.3).abs().max().item<double>() < 1e-6);
}

TEST_CASE("a region whose radius is wrong falls back to the shot; the rest keeps the fit") {
    // Rack focus; the right half of each frame's radius map is another frame's (the focus pull
    // run backwards): the shared atlas cannot explain both halves' frames alike.
    test::TinyClip c = test::make_tiny("confidence_wrong_radius", "rack", "160x90");
    const int T = 8, W = 160, H = 90;
    const auto coc = read_all_frames((c.clip / "coc_%04d.exr").string());
    REQUIRE(static_cast<int>(coc.size()) == T);
    const fs::path wrong = c.dir / "wrong";
    fs::create_directories(wrong);
    Image half(W, H, 1, 0.0f);  // 1 on the right half: the wrong region
    for (int y = 0; y < H; ++y)
        for (int x = W / 2; x < W; ++x) half.pixels[y * W + x] = 1.0f;
    for (int t = 0; t < T; ++t) {
        Image m = coc[t];
        for (int y = 0; y < H; ++y)
            for (int x = W / 2; x < W; ++x) m.pixels[y * W + x] = coc[T - 1 - t].pixels[y * W + x];
        char name[32];
        std::snprintf(name, sizeof name, "coc_%04d.exr", t);
        write_image_file((wrong / name).string(), m, PixelFormat::ExrFloat, false);
    }
    // κ alone (the sharper-view rule off): the wrong half is told by the frames' disagreement.
    auto r = test::cli("fit '" + c.project.string() +
                       "' --iters 200 --set fit.sharper_view_px=0 --coc '" +
                       (wrong / "coc_%04d.exr").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const auto sharp = test::export_sharp(c, "sharp");
    r = test::cli("export '" + c.project.string() + "' --what confidence --format exr32 --out '" +
                  (c.dir / "conf").string() + "'");
    REQUIRE(r.code == 0);
    const auto conf = read_all_frames((c.dir / "conf/confidence_%04d.exr").string());
    const auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((c.clip / "input_%04d.png").string());
    double out_wrong = 0, in_wrong = 0, out_right = 0, in_right = 0, k_wrong = 0, k_right = 0;
    for (int t = 0; t < T; ++t) {
        out_wrong += masked_psnr(sharp[t], gt[t], half, MaskRegion::Inside) / T;
        in_wrong += masked_psnr(input[t], gt[t], half, MaskRegion::Inside) / T;
        out_right += masked_psnr(sharp[t], gt[t], half, MaskRegion::Outside) / T;
        in_right += masked_psnr(input[t], gt[t], half, MaskRegion::Outside) / T;
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x)
                (x < W / 2 ? k_right : k_wrong) += conf[t].pixels[y * W + x] / (T * H * W / 2.0);
    }
    MESSAGE("wrong radius half: input " << in_wrong << " dB, output " << out_wrong
                                        << " dB, confidence " << k_wrong);
    MESSAGE("true radius half: input " << in_right << " dB, output " << out_right
                                       << " dB, confidence " << k_right);
    CHECK(out_wrong > in_wrong - 0.5);  // never (much) worse than the shot
    CHECK(out_right > in_right + 1.0);  // where the model is right, it still fixes the shot
    // And the confidence pass says where: the wrong half's residual passes what its noise and
    // the model's change there explain more often than the right half's.
    CHECK(k_wrong < k_right - 0.1);

    // The default sharper-view rule (2 px) acts on the output only: the same fit exported with
    // it keeps the shot where a frame is its own sharpest view. No frame falls below its input,
    // and the right half, which the focus pull shows sharper in other frames, still gains.
    test::set_project_setting(c.project, "fit.sharper_view_px", std::nullopt);
    r = test::cli("export '" + c.project.string() + "' --what sharp --format exr32 --out '" +
                  (c.dir / "sharp_default").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    // Export says how much of the plate is the shot because no other frame saw it sharper.
    const auto said = r.output.find("% that no other frame saw sharper");
    REQUIRE(said != std::string::npos);
    const auto from = r.output.rfind(' ', said) + 1;
    CHECK(std::stod(r.output.substr(from, said - from)) > 5.0);
    const auto gamma = read_all_frames((c.dir / "sharp_default/sharp_%04d.exr").string());
    double worst = 1e9, out_right_g = 0;
    for (int t = 0; t < T; ++t) {
        worst = std::min(worst, psnr(gamma[t], gt[t]) - psnr(input[t], gt[t]));
        out_right_g += masked_psnr(gamma[t], gt[t], half, MaskRegion::Outside) / T;
    }
    MESSAGE("default sharper-view rule: worst frame " << worst << " dB, true radius half "
                                                      << out_right_g << " dB");
    CHECK(worst > -0.5);
    CHECK(out_right_g > in_right + 0.2);
}

TEST_CASE(
    "a radius too large in every frame: no frame saw the scene sharp, the plate is the shot") {
    // The true radius plus 4 px in every frame: the frames agree on a wrong sharp frame (it
    // reblurs well), so only the sharpest radius seen (fit.trust_seen_px) can tell.
    test::TinyClip c = test::make_tiny("confidence_radius_plus4", "rack", "160x90");
    const int T = 8;
    const auto coc = read_all_frames((c.clip / "coc_%04d.exr").string());
    REQUIRE(static_cast<int>(coc.size()) == T);
    const fs::path wrong = c.dir / "wrong";
    fs::create_directories(wrong);
    for (int t = 0; t < T; ++t) {
        Image m = coc[t];
        for (float& v : m.pixels) v += 4.0f;
        char name[32];
        std::snprintf(name, sizeof name, "coc_%04d.exr", t);
        write_image_file((wrong / name).string(), m, PixelFormat::ExrFloat, false);
    }
    auto r = test::cli("fit '" + c.project.string() + "' --iters 150 --coc '" +
                       (wrong / "coc_%04d.exr").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = test::cli("export '" + c.project.string() + "' --what sharp --format exr32 --out '" +
                  (c.dir / "sharp").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    // Export says so: the plate is the shot where the fit cannot explain the shot, and where it
    // can (the frames agree on the wrong answer) because no frame saw it sharp.
    auto share = [&](const std::string& what) {
        const auto at = r.output.find(what);
        REQUIRE(at != std::string::npos);
        const auto from = r.output.rfind(' ', at) + 1;
        return std::stod(r.output.substr(from, at - from));
    };
    const double unseen = share("% that no frame saw sharp");
    CHECK(unseen > 20.0);
    CHECK(share("% of pixels the fit cannot explain") + unseen > 95.0);
    const auto sharp = read_all_frames((c.dir / "sharp/sharp_%04d.exr").string());
    r = test::cli("export '" + c.project.string() + "' --what confidence --format exr32 --out '" +
                  (c.dir / "conf").string() + "'");
    REQUIRE(r.code == 0);
    const auto conf = read_all_frames((c.dir / "conf/confidence_%04d.exr").string());
    const auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((c.clip / "input_%04d.png").string());
    double out = 0, in = 0, k = 0, worst = 1e9;
    for (int t = 0; t < T; ++t) {
        const double o = psnr(sharp[t], gt[t]), i = psnr(input[t], gt[t]);
        out += o / T, in += i / T, worst = std::min(worst, o - i);
        double sum = 0;
        for (size_t p = 0; p < conf[t].pixels.size(); p += conf[t].channels)
            sum += conf[t].pixels[p];
        k += sum / (conf[t].pixels.size() / conf[t].channels) / T;
    }
    MESSAGE("radius + 4 px: input " << in << " dB, output " << out << " dB (worst frame " << worst
                                    << " dB), confidence " << k);
    CHECK(out > in - 0.5);
    CHECK(worst > -0.5);
    CHECK(k < 0.2);
}

TEST_CASE("separable max and min filters equal max pooling over the square window") {
    // Masks are grown and eroded by windows of hundreds of px at 1080p (a subject's reach):
    // ops/morphology.h does it in two 1-D passes.
    namespace F = torch::nn::functional;
    torch::manual_seed(3);
    const auto x = torch::rand({2, 1, 37, 53});
    for (int r : {0, 1, 4, 17}) {
        CAPTURE(r);
        const auto pooled =
            r == 0 ? x : F::max_pool2d(x, F::MaxPool2dFuncOptions(2 * r + 1).stride(1).padding(r));
        CHECK(torch::equal(max_filter(x, r), pooled));
        const auto eroded =
            r == 0 ? x
                   : -F::max_pool2d(-x, F::MaxPool2dFuncOptions(2 * r + 1).stride(1).padding(r));
        CHECK(torch::equal(min_filter(x, r), eroded));
    }
    // A window wider than the map: every pixel takes the map's extreme.
    CHECK(torch::equal(max_filter(x, 80)[0], x[0].amax({1, 2}, true).expand({1, 37, 53})));
    // Windows from 4 px take the running max (van Herk / Gil-Werman): several planes, a window
    // wider than the map along one axis only, a view that is not contiguous.
    const auto y = torch::rand({2, 3, 23, 71}).transpose(2, 3);  // [2,3,71,23], strided
    for (int r : {4, 5, 12, 30}) {
        CAPTURE(r);
        CHECK(torch::equal(
            max_filter(y, r),
            F::max_pool2d(y, F::MaxPool2dFuncOptions(2 * r + 1).stride(1).padding(r))));
    }
}

TEST_CASE("the separable box mean equals the square average pool over a replicated border") {
    // The focal-stack radius filters 29 cost maps a frame: two 1-D passes instead of (2r+1)².
    namespace F = torch::nn::functional;
    torch::manual_seed(4);
    const auto x = torch::rand({3, 2, 29, 41});
    for (int r : {0, 1, 4, 9}) {
        CAPTURE(r);
        const auto ref =
            r == 0
                ? x
                : F::avg_pool2d(F::pad(x, F::PadFuncOptions({r, r, r, r}).mode(torch::kReplicate)),
                                F::AvgPool2dFuncOptions(2 * r + 1).stride(1));
        const auto got = box_filter(x, r);
        REQUIRE(got.sizes() == x.sizes());
        CHECK((got - ref).abs().max().item<float>() < 1e-5f);  // float sums of 19² terms
    }
    // A flat map stays flat; a window past the border only repeats the edge.
    CHECK(torch::allclose(box_filter(torch::full({1, 1, 5, 7}, 0.25f), 6),
                          torch::full({1, 1, 5, 7}, 0.25f)));
}
