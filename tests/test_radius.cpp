// Radius estimation: the focal stack (stack_coc.h) with its absolute floor from edges and tile
// spectra, and each layer's radius (split_radius_by_layer).
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "io/clip.h"
#include "fit/fit_setup.h"
#include "model/atlas_geometry.h"
#include "radius/stack_coc.h"
#include "radius/stack_costs.h"
#include "project/project.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("radius from the clip as a focal stack matches the ground truth on a focus sweep") {
    TinyClip c = make_tiny("fit_stack_coc", "tripod", "128x72");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    std::vector<float> err;
    double sum_gt = 0;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 4; y < d->height - 4; ++y)
            for (int x = 4; x < d->width - 4; ++x) {
                const float g = gt[t].at(x, y, 0);
                err.push_back(std::abs(d->radius[t][y][x].item<float>() - g));
                sum_gt += g;
            }
    std::sort(err.begin(), err.end());
    const double median = err[err.size() / 2], mean_gt = sum_gt / err.size();
    MESSAGE("focal-stack radius: median abs error " << median << " px (mean true radius " << mean_gt
                                                    << " px)");
    CHECK(median < 0.35 * mean_gt);

    // The grid's blurs by FFT (the default) against the direct blur (the reference path): they
    // differ only within the kernel's reach of the border; the floor and the spread carry a
    // little of that inward (0.04 px here, against a mean radius of 1.3 px).
    StackCocOptions direct;
    direct.direct_blur = true;
    const auto fft = estimate_radius_from_stack(*d), ref = estimate_radius_from_stack(*d, direct);
    const auto inner = [&](const torch::Tensor& r) {
        return r.narrow(1, 16, d->height - 32).narrow(2, 16, d->width - 32);
    };
    const double mean_diff = (fft - ref).abs().mean().item<double>();
    const double inner_diff = (inner(fft) - inner(ref)).abs().mean().item<double>();
    MESSAGE("FFT against direct blurs: mean |radius difference| "
            << mean_diff << " px, " << inner_diff << " px 16 px inside");
    CHECK(inner_diff < 0.06);
    CHECK(mean_diff < 0.1);
}

TEST_CASE(
    "focal-stack radius on a pan with fixed focus: content entering the frame and a subject never "
    "in focus are not read as more blur than they have") {
    // Focus stays on the wall, so no view of any point is sharper than another: relative to its
    // sharpest view every pixel has radius ~0, and what blur there is comes from the floor
    // (edge_blur.h), which must not invent any: content entering the pan is compared with the
    // canvas, not with smeared border pixels, and the subject's automatic mask holds wall texture.
    // At this size (8 frames of 128x72, the wall 0.2-1.5 px) the floor has few edges to go by
    // and overshoots at 1% of the pixels, hence a bound of 1.75 px rather than near 0.
    TinyClip c = make_tiny("fit_stack_pan", "pan", "128x72");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    std::vector<float> over, over_wall, over_edge;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                const float o = d->radius[t][y][x].item<float>() - gt[t].at(x, y, 0),
                            a = alpha[t].at(x, y, 0);
                over.push_back(o);
                (a < 0.01f ? over_wall : over_edge).push_back(o);
            }
    auto p99_of = [](std::vector<float>& v) {
        std::sort(v.begin(), v.end());
        return v[v.size() * 99 / 100];
    };
    const float p99 = p99_of(over);
    MESSAGE("pan: 99th percentile of (estimated - true radius) "
            << p99 << " px; wall " << p99_of(over_wall) << ", subject " << p99_of(over_edge));
    CHECK(p99 < 1.75f);
}

TEST_CASE(
    "the stack's absolute floor: a wall and a subject never in focus read their blur, not 0") {
    // Synth pan: focus fixed on the far wall, so the stack alone reads ~0 everywhere (above);
    // the truth is 0.4-3.1 px on the wall (by the row) and 5.7 px on the subject at this size.
    // The floor (edge_blur.h: each frame's isolated edges, a robust smooth surface per layer)
    // restores it.
    TinyClip c = make_tiny("fit_stack_floor", "pan", "256x144");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    StackCocOptions relative;
    relative.absolute = false;
    auto rel = estimate_radius_from_stack(*d, relative);
    // Frames run on the cores (each with its own blurs; the composites' sums in two fixed
    // parts): one thread reads the same radius to the bit, floor and all.
    {
        const int threads = at::get_num_threads();
        at::set_num_threads(1);
        const auto one = estimate_radius_from_stack(*d);
        at::set_num_threads(std::max(2, threads));
        const auto two = estimate_radius_from_stack(*d);
        at::set_num_threads(threads);
        CHECK(torch::equal(one, two));
    }
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    struct Err {
        double abs_floor = 0, abs_rel = 0, truth = 0;
        int n = 0;
    } wall, subject;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                const float g = gt[t].at(x, y, 0), a = alpha[t].at(x, y, 0);
                Err* e = a > 0.99f ? &subject : (a < 0.01f && g > 1.5f) ? &wall : nullptr;
                if (!e) continue;
                e->abs_floor += std::abs(d->radius[t][y][x].item<float>() - g);
                e->abs_rel += std::abs(rel[t][y][x].item<float>() - g);
                e->truth += g;
                ++e->n;
            }
    REQUIRE(wall.n > 0);
    REQUIRE(subject.n > 0);
    for (Err* e : {&wall, &subject}) {
        e->abs_floor /= e->n;
        e->abs_rel /= e->n;
        e->truth /= e->n;
    }
    MESSAGE("wall (true radius > 1.5 px, mean " << wall.truth << "): mean abs error "
                                                << wall.abs_rel << " px relative only, "
                                                << wall.abs_floor << " with the floor");
    MESSAGE("subject (mean " << subject.truth << "): " << subject.abs_rel << " px relative only, "
                             << subject.abs_floor << " with the floor");
    // 8 frames at this size hold few isolated edges; synth pan at 320x180x30 reads the wall to
    // 0.43-0.62 px and the subject to 0.1-1.2 px (docs/method.md, Radius estimation).
    CHECK(wall.abs_floor < 0.6 * wall.abs_rel);
    CHECK(subject.abs_floor < 0.6 * subject.abs_rel);
}

TEST_CASE(
    "the stack's absolute floor past what edges measure: a wall blurred 5-9 px is read from tile "
    "spectra, without holes") {
    // Synth walkout: focus stays on the subject's first depth, the wall is blurred 9.3 px at the
    // top to 5.3 at the bottom in every frame. Edges read it 30% low (edge_blur.h), so the floor
    // comes from tile spectra (spectral_blur.h): a plane over the tiles' readings, held as a least
    // radius where the stack's relative readings err.
    TinyClip c = make_tiny("fit_stack_spectral", "walkout", "320x180");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    StackCocReport report;
    auto est = estimate_radius_from_stack(*d, {}, &report);
    MESSAGE(report.summary);
    CHECK(report.summary.find("tile spectra") != std::string::npos);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    std::vector<float> ratio;
    double abs_err = 0, truth = 0;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                if (alpha[t].at(x, y, 0) > 0.01f) continue;
                const float g = gt[t].at(x, y, 0), e = est[t][y][x].item<float>();
                abs_err += std::abs(e - g);
                truth += g;
                ratio.push_back(e / g);
            }
    REQUIRE(!ratio.empty());
    std::sort(ratio.begin(), ratio.end());
    const double p01 = ratio[ratio.size() / 100], p50 = ratio[ratio.size() / 2],
                 p95 = ratio[ratio.size() * 95 / 100], p99 = ratio[ratio.size() * 99 / 100];
    MESSAGE("wall (mean " << truth / ratio.size() << " px): mean abs error "
                          << abs_err / ratio.size()
                          << " px; estimate / truth at the 1st, 50th, 95th, 99th percentile " << p01
                          << ", " << p50 << ", " << p95 << ", " << p99);
    // 8 frames read it to 0.25 px, 30 frames (two layers) to 0.09-0.14 (docs/method.md, Radius
    // estimation); a radius 15% off the truth at this blur costs more than the whole gain
    // (docs/method.md, Radius estimation).
    CHECK(abs_err / ratio.size() < 0.5);
    CHECK(p50 > 0.93);
    CHECK(p50 < 1.05);
    CHECK(p01 > 0.8);  // no holes where the relative reading alone would have been taken
    // Over: at this size the subject gets no layer of its own (8 frames), and its rim, blurred
    // by up to 6 px, passes over 1-2% of the wall, which the stack reads as blur added.
    CHECK(p95 < 1.15);
}

// Each layer's radius split (split_radius_by_layer) over a wall whose radius ramps from 1 px by
// `slope` px per column (`ramp` receives it), with a subject of radius `r` in frame 0's box
// `subject` and frame 0's mask in box `mask` (boxes: row, rows, column, columns).
static FitData split_over_ramp(int frames, int height, int width, double slope,
                               std::array<int, 4> subject, float r, std::array<int, 4> mask,
                               torch::Tensor& ramp) {
    FitData d;
    d.frames = frames, d.height = height, d.width = width;
    d.has_subject = true;
    ramp = (1.0 + torch::arange(width, torch::kFloat32) * slope)
               .view({1, 1, width})
               .expand({frames, height, width});
    d.radius = ramp.clone();
    d.radius[0].narrow(0, subject[0], subject[1]).narrow(1, subject[2], subject[3]).fill_(r);
    d.mask = torch::zeros({frames, 1, height, width});
    d.mask[0].narrow(1, mask[0], mask[1]).narrow(2, mask[2], mask[3]).fill_(1.0);
    split_radius_by_layer(d);
    return d;
}

TEST_CASE(
    "each layer's radius: the subject's spreads past its silhouette, the wall's continues behind "
    "it") {
    // Two frames 40x30: a 12x10 subject at radius 5 in front of a wall whose radius ramps
    // 1 → 2.45 px left to right; frame 1 has no subject.
    torch::Tensor ramp;
    FitData d = split_over_ramp(2, 30, 40, 0.0375, {10, 10, 14, 12}, 5.0f, {10, 10, 14, 12}, ramp);
    REQUIRE(d.radius_fg.defined());
    REQUIRE(d.radius_bg.defined());
    {  // A frame a core: one thread splits the same.
        const int threads = at::get_num_threads();
        at::set_num_threads(1);
        FitData one = d;
        split_radius_by_layer(one);
        at::set_num_threads(threads);
        CHECK(torch::equal(one.radius_fg, d.radius_fg));
        CHECK(torch::equal(one.radius_bg, d.radius_bg));
    }
    // Where each layer is sure (2 px inside its own region) it keeps the map as given.
    CHECK(torch::allclose(d.radius_fg[0].narrow(0, 12, 6).narrow(1, 16, 8),
                          torch::full({6, 8}, 5.0f)));
    CHECK(torch::allclose(d.radius_bg[0].narrow(0, 0, 8), ramp[0].narrow(0, 0, 8)));
    // The subject's radius reaches past its edge (its blurred edge scatters over the wall).
    CHECK(d.radius_fg[0][15][10].item<float>() == doctest::Approx(5.0).epsilon(0.02));
    CHECK(d.radius_fg[0][5][20].item<float>() == doctest::Approx(5.0).epsilon(0.02));
    // Behind the subject the wall keeps the wall's radius, within its ramp's range there.
    auto behind = d.radius_bg[0].narrow(0, 10, 10).narrow(1, 14, 12);
    CHECK(behind.min().item<float>() > 1.4f);
    CHECK(behind.max().item<float>() < 2.1f);
    // A frame without the subject keeps the map for both layers.
    CHECK(torch::equal(d.radius_fg[1], d.radius[1]));
    CHECK(torch::equal(d.radius_bg[1], d.radius[1]));
    // One layer: nothing split.
    d.mask = torch::Tensor();
    split_radius_by_layer(d);
    CHECK_FALSE(d.radius_fg.defined());
    CHECK(d.layer_radius(true).data_ptr() == d.radius.data_ptr());
}

TEST_CASE(
    "each layer's radius from a blob of a mask: the rim keeps the subject's radius, a missed part "
    "the wall's") {
    // One frame 60x50: a 16x15 subject at radius 6 (rows 15-29, columns 20-35) in front of a wall
    // whose radius ramps 1 -> 2.5 px left to right. Its automatic mask is a blob 3 px wider on
    // top, left and right (wall pixels, the wall's radius) that misses its bottom 4 rows.
    torch::Tensor ramp;
    FitData d = split_over_ramp(1, 50, 60, 0.025, {15, 15, 20, 16}, 6.0f, {12, 14, 17, 23}, ramp);
    REQUIRE(d.radius_fg.defined());
    // The mask's rim holds the wall's radius; the subject's layer takes the subject's there.
    CHECK(d.radius_fg[0][13][18].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    CHECK(d.radius_fg[0][20][38].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    CHECK(d.radius_fg[0][20][28].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    // The part the mask missed holds the subject's radius; the wall's layer keeps the wall's.
    auto missed = d.radius_bg[0].narrow(0, 28, 2).narrow(1, 20, 16);
    CHECK(missed.max().item<float>() < 2.6f);
    CHECK(missed.min().item<float>() > 1.0f);
    // Far from the subject the wall's map is as given.
    CHECK(torch::allclose(d.radius_bg[0].narrow(0, 40, 10), ramp[0].narrow(0, 40, 10)));
}

TEST_CASE(
    "the stack's wall behind a sharp subject that walked off: seen blurred, it keeps its floor") {
    // A wall of flat blocks blurred 3 px (never in focus) and a sharp, high-contrast subject
    // crossing it. The wall's composite weighs its own views against the sharpest of them; against
    // every view's, the points the subject had covered kept weights of (contrast ratio)^8 ~ 0
    // there, counted as never seen, and kept no floor: holes of radius 0 in every later frame
    // (synth walkout: 27% of a 20x40 px block read 0-0.6 px for 6 px).
    const int T = 8, H = 64, W = 96;
    torch::manual_seed(5);
    LensBlurParams bp;
    bp.kernel = BlurKernel::Pillbox;
    auto blocks = torch::rand({3, H / 8, W / 8}) * 0.3 + 0.3;
    auto wall = lens_blur(
        torch::repeat_interleave(torch::repeat_interleave(blocks, 8, 1), 8, 2).contiguous(),
        torch::full({H, W}, 3.0f), bp);
    auto ys = torch::arange(H).view({H, 1}), xs = torch::arange(W).view({1, W});
    auto checker = ((ys / 2 + xs / 2) % 2).to(torch::kFloat32).expand({3, H, W}) * 0.95 + 0.02;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.blur = bp;
    std::vector<torch::Tensor> frames, masks;
    for (int t = 0; t < T; ++t) {
        const int x0 = 6 + 8 * t;  // 24x24, 8 px a frame
        auto m = ((ys >= 20) & (ys < 44) & (xs >= x0) & (xs < x0 + 24))
                     .to(torch::kFloat32)
                     .view({1, H, W});
        auto subject = torch::roll(checker, {8 * t}, {2});  // its texture moves with it
        frames.push_back(m * subject + (1 - m) * wall);
        masks.push_back(m);
    }
    d.input = torch::stack(frames).contiguous();
    d.mask = torch::stack(masks).contiguous();
    d.has_subject = true;
    d.to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    auto est = estimate_radius_from_stack(d);
    // The last frame's wall where the subject stood in the first (x 6-29, clear of it by then).
    auto seen_later = est[T - 1].narrow(0, 24, 16).narrow(1, 8, 20);
    auto elsewhere = est[T - 1].narrow(0, 4, 12).narrow(1, 8, 80);
    MESSAGE("wall behind the subject's first place: "
            << seen_later.mean().item<float>() << " px (min " << seen_later.min().item<float>()
            << "); elsewhere " << elsewhere.mean().item<float>() << " px; truth 3");
    CHECK(seen_later.min().item<float>() > 0.6f * elsewhere.mean().item<float>());
}

TEST_CASE("the subject's radius over boxes around it equals the pass over the whole frames") {
    // A 24x24 subject crossing a 200x120 frame, its focus racking 0.5 -> 4 px, before a wall of
    // blocks blurred 2 px: its pass reads boxes of about a fifth of the frame.
    const int T = 8, H = 120, W = 200;
    torch::manual_seed(7);
    LensBlurParams bp;
    bp.kernel = BlurKernel::Pillbox;
    auto blocks = torch::rand({3, H / 8, W / 8}) * 0.3 + 0.3;
    auto wall = lens_blur(
        torch::repeat_interleave(torch::repeat_interleave(blocks, 8, 1), 8, 2).contiguous(),
        torch::full({H, W}, 2.0f), bp);
    auto ys = torch::arange(H).view({H, 1}), xs = torch::arange(W).view({1, W});
    auto texture = torch::repeat_interleave(
        torch::repeat_interleave(torch::rand({3, H / 4, W / 4}) * 0.8 + 0.1, 4, 1), 4, 2);
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.blur = bp;
    std::vector<torch::Tensor> frames, masks;
    for (int t = 0; t < T; ++t) {
        const int x0 = 40 + 12 * t, y0 = 40 + 2 * t;
        auto m = ((ys >= y0) & (ys < y0 + 24) & (xs >= x0) & (xs < x0 + 24))
                     .to(torch::kFloat32)
                     .view({1, H, W});
        auto moved = torch::roll(texture, {2 * t, 12 * t}, {1, 2}).contiguous();
        auto subject = lens_blur(moved, torch::full({H, W}, 0.5f * (1 + t)), bp);
        frames.push_back(m * subject + (1 - m) * wall);
        masks.push_back(m);
    }
    d.input = torch::stack(frames).contiguous();
    d.mask = torch::stack(masks).contiguous();
    d.has_subject = true;
    d.to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    // With the grid's blurs made directly the two agree to rounding; by FFT (the default) the
    // float32 transform of a box and of a frame round differently, and where a cost's minimum
    // is flat the parabola's step moves with it.
    const auto in = d.mask.squeeze(1) > 0.5;
    for (bool direct : {true, false}) {
        StackCocOptions boxes_on, whole;
        whole.subject_boxes = false;
        boxes_on.direct_blur = whole.direct_blur = direct;
        StackCocReport rb, rw;
        const auto boxes = estimate_radius_from_stack(d, boxes_on, &rb),
                   ref = estimate_radius_from_stack(d, whole, &rw);
        const auto diff = (boxes - ref).abs().masked_select(in);
        MESSAGE(std::string(direct ? "direct" : "FFT")
                << " blurs, subject over boxes against whole frames: "
                << "mean |difference| " << diff.mean().item<float>() << " px, largest "
                << diff.max().item<float>() << " px; the subject's radius "
                << ref.masked_select(in).mean().item<float>() << " px");
        CHECK(diff.mean().item<float>() < (direct ? 0.002f : 0.03f));
        CHECK(diff.max().item<float>() < (direct ? 0.05f : 0.3f));
        CHECK(rb.summary == rw.summary);
        // Outside the subject both are the wall's pass.
        CHECK(torch::equal(boxes.masked_select(~in), ref.masked_select(~in)));
    }
}

TEST_CASE("a whole-pixel shift onto the canvas, copied, equals the sampler's") {
    torch::manual_seed(11);
    const auto src = torch::rand({1, 3, 20, 30}), ones = torch::ones({1, 1, 20, 30});
    for (auto [dx, dy] : {std::pair{0, 0}, {-2, -2}, {3, -1}, {-5, 4}, {31, 0}}) {
        const auto m = translation(dx, dy);
        for (bool zeros : {false, true}) {
            const auto& x = zeros ? ones : src;
            const auto copy = warp_to_canvas(x, m, 24, 34, zeros),
                       sampled = warp_to_canvas(x, m, 24, 34, zeros, false);
            INFO("shift (" << dx << ", " << dy << "), " << (zeros ? "zeros" : "border"));
            CHECK((copy - sampled).abs().max().item<float>() < 1e-5f);
        }
    }
}

TEST_CASE("the focal stack's fused costs and running argmin equal their tensor-op references") {
    torch::manual_seed(7);
    // Costs on a coarse grid of values, so that ties (the first least wins) occur often; sizes
    // that split unevenly over the threads.
    const int64_t H = 67, W = 301, K = 13;
    RunningArgmin fast, ref;
    for (int64_t k = 0; k < K; ++k) {
        auto ck = torch::randint(0, 6, {H, W}).to(torch::kFloat32);
        fast.add(ck, k);
        ref.add_reference(ck, k);
    }
    CHECK(torch::equal(fast.best, ref.best));
    CHECK(torch::equal(fast.cmin, ref.cmin));
    CHECK(torch::equal(fast.cmax, ref.cmax));
    CHECK(torch::equal(fast.c0, ref.c0));
    CHECK(torch::equal(fast.c1, ref.c1));
    CHECK(torch::equal(fast.c2, ref.c2));
    CHECK(fast.best.max().item<int64_t>() > 0);  // the argmin moved past the first radius
    auto a = torch::rand({3, H, W}), b = torch::rand({3, H, W});
    CHECK(torch::allclose(squared_difference(a, b), (a - b).pow(2).sum(0, true).unsqueeze(0), 1e-6,
                          1e-7));
}
