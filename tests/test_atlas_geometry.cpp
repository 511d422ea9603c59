// Atlas geometry: the subject's track (position and size) and the automatic masks cleaned
// along it.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

#include "model/atlas_geometry.h"
#include "model/fit_model.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("subject track follows the subject's flow where its masks lose part of it") {
    // A subject moving 1.5 px a frame to the right; frames 2-4 mask only its lower half (a
    // blurred subject's automatic mask loses its head), so their centroids drop 6 px.
    const int T = 7, H = 40, W = 64;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.mask = torch::zeros({T, 1, H, W});
    for (int t = 0; t < T; ++t) {
        const int x0 = 10 + int(std::lround(1.5 * t));
        const bool half = t >= 2 && t <= 4;
        d.mask[t][0].narrow(0, half ? 20 : 8, half ? 12 : 24).narrow(1, x0, 16).fill_(1.0f);
    }
    d.flow_fwd = torch::zeros({T - 1, 2, H, W});
    d.flow_fwd.select(1, 0).fill_(1.5f);  // the subject's motion (the wall's does not matter:
    d.flow_valid = torch::ones({T - 1, 1, H, W});  // only the mask's core is read)
    std::vector<double> vx, vy;
    subject_track(d, vx, vy);
    for (int t = 0; t < T; ++t) {
        CHECK(vx[t] - vx[0] == doctest::Approx(1.5 * t).epsilon(1e-6));
        CHECK(vy[t] - vy[0] == doctest::Approx(0.0).epsilon(1e-6));
    }
    // Anchored on the median centroid: the full masks' centre (y = 19.5), not the halves'.
    CHECK(vy[0] == doctest::Approx(19.5).epsilon(1e-6));
    // Without flow (or for an earlier build's checkpoint) the smoothed centroids, which follow
    // the masks down.
    d.legacy_subject_track = true;
    subject_track(d, vx, vy);
    CHECK(vy[3] > 22.0);
}

TEST_CASE("subject track: a subject walking away is followed in size as well") {
    // A square subject centred at (40, 30) shrinking by 10% a frame; the flow is the expansion
    // about that centre (everywhere: only the mask's core is read).
    const int T = 5, H = 64, W = 80;
    const double cx = 40, cy = 30, k = 0.9;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.mask = torch::zeros({T, 1, H, W});
    for (int t = 0; t < T; ++t) {
        const int half = int(std::lround(24 * std::pow(k, t)));
        d.mask[t][0]
            .narrow(0, int(cy) - half, 2 * half)
            .narrow(1, int(cx) - half, 2 * half)
            .fill_(1.0f);
    }
    auto g = torch::meshgrid({torch::arange(H, torch::kFloat32), torch::arange(W, torch::kFloat32)},
                             "ij");
    d.flow_fwd = torch::stack({(k - 1) * (g[1] - cx), (k - 1) * (g[0] - cy)})
                     .unsqueeze(0)
                     .repeat({T - 1, 1, 1, 1});
    d.flow_valid = torch::ones({T - 1, 1, H, W});
    std::vector<double> vx, vy, sc;
    subject_track(d, vx, vy, &sc);
    for (int t = 0; t < T; ++t) {
        CHECK(sc[t] == doctest::Approx(std::pow(k, t)).epsilon(1e-3));
        // The subject's centre and a corner land on the same track coordinates in every frame.
        const double corner = 20 * std::pow(k, t);
        auto m = subject_to_track(vx[t], vy[t], sc[t]);
        auto c = torch::matmul(m, torch::tensor({cx, cy, 1.0}, torch::kFloat64));
        auto e = torch::matmul(m, torch::tensor({cx + corner, cy - corner, 1.0}, torch::kFloat64));
        auto m0 = subject_to_track(vx[0], vy[0], sc[0]);
        auto c0 = torch::matmul(m0, torch::tensor({cx, cy, 1.0}, torch::kFloat64));
        auto e0 = torch::matmul(m0, torch::tensor({cx + 20, cy - 20, 1.0}, torch::kFloat64));
        CHECK((c - c0).abs().max().item<double>() < 0.05);
        CHECK((e - e0).abs().max().item<double>() < 0.05);
    }
    // A subject of one size keeps scale 1 (the translation track, bit for bit).
    d.flow_fwd.zero_();
    for (int t = 0; t < T; ++t) d.mask[t] = d.mask[0];
    subject_track(d, vx, vy, &sc);
    for (double s : sc) CHECK(s == 1.0);
}

TEST_CASE(
    "automatic masks cleaned along the subject's track: a passing blob is dropped, a lost frame "
    "refilled") {
    // A 12x12 subject moving 2 px a frame to the right over 8 frames of 80x40 (flow to match).
    // Frame 3's mask also holds a wall tile; frame 5's lost the subject.
    FitData d;
    d.frames = 8, d.height = 40, d.width = 80;
    d.has_subject = true;
    d.input = torch::zeros({8, 3, 40, 80});
    d.radius = torch::zeros({8, 40, 80});
    d.to_ref = torch::eye(3, torch::kFloat64).expand({8, 3, 3}).clone();
    d.flow_fwd = torch::zeros({7, 2, 40, 80});
    d.flow_fwd.select(1, 0).fill_(2.0f);
    d.flow_valid = torch::ones({7, 1, 40, 80});
    d.mask = torch::zeros({8, 1, 40, 80});
    for (int t = 0; t < 8; ++t)
        if (t != 5) d.mask[t][0].narrow(0, 14, 12).narrow(1, 10 + 2 * t, 12).fill_(1.0f);
    d.mask[3][0].narrow(0, 0, 8).narrow(1, 60, 14).fill_(1.0f);
    auto want = d.mask.clone();
    want[3][0].narrow(0, 0, 8).narrow(1, 60, 14).zero_();
    want[5][0].narrow(0, 14, 12).narrow(1, 20, 12).fill_(1.0f);
    // The frames are cleaned on the cores: one thread gives the same.
    FitData serial = d;
    const int threads = at::get_num_threads();
    at::set_num_threads(1);
    const std::string line_serial = clean_subject_masks(serial);
    at::set_num_threads(std::max(2, threads));
    const std::string line = clean_subject_masks(d);
    at::set_num_threads(threads);
    CHECK(line == line_serial);
    CHECK(torch::equal(serial.mask, d.mask));
    MESSAGE(line);
    CHECK(line.find("1 part(s)") != std::string::npos);
    CHECK(line.find("1 frame(s)") != std::string::npos);
    CHECK((d.mask > 0.5).eq(want > 0.5).all().item<bool>());
    // A subject leaving the frame is not put back: its mask shrinks as the moved one would.
    FitData e = d;
    e.mask = torch::zeros({8, 1, 40, 80});
    for (int t = 0; t < 8; ++t) {
        const int x0 = 50 + 4 * t, x1 = std::min(80, x0 + 12);
        if (x1 > x0) e.mask[t][0].narrow(0, 14, 12).narrow(1, x0, x1 - x0).fill_(1.0f);
    }
    e.flow_fwd.select(1, 0).fill_(4.0f);
    auto before = e.mask.clone();
    clean_subject_masks(e);
    CHECK(torch::equal(e.mask > 0.5, before > 0.5));
}

TEST_CASE("fuse_frames: each frame pulled in over its window equals the whole fusion there") {
    // Three 24x20 frames translated into a 40x30 atlas, each weighted only over a patch: their
    // windows (the patches' mapped boxes) hold every texel a weight reaches, so the fusion over
    // windows equals the whole one wherever a frame saw, and the fallback fills the rest.
    torch::manual_seed(4);
    const int64_t T = 3, H = 20, W = 24, Ha = 30, Wa = 40;
    auto src = torch::rand({T, 3, H, W});
    auto weight = torch::zeros({T, 1, H, W});
    std::vector<torch::Tensor> mats;
    for (int64_t t = 0; t < T; ++t) {
        weight[t].narrow(1, 4 + t, 6).narrow(2, 3 + 2 * t, 8).fill_(0.5 + t);
        mats.push_back(translation(5.0 + 3.0 * t, 4.0 + 1.5 * t));
    }
    const auto to_atlas = torch::stack(mats).to(torch::kFloat32);
    const auto whole = fuse_frames(to_atlas, Ha, Wa, src, weight);
    std::vector<TexelBox> boxes;
    for (int64_t t = 0; t < T; ++t)
        boxes.push_back(mapped_box(to_atlas, t, 3.0 + 2 * t - 1, 4.0 + t - 1, 10.0 + 2 * t + 1,
                                   9.0 + t + 1, 3.0, Ha, Wa));
    CHECK(boxes[1].x0 == 4 + 8 - 3);  // x 5 − 1 mapped by +8, grown by 3
    const auto fallback = torch::full({3, Ha, Wa}, -1.0f);
    const auto windowed = fuse_frames(
        to_atlas, Ha, Wa, [&](int64_t t) { return src[t]; }, [&](int64_t t) { return weight[t]; },
        {}, [&](int64_t t) { return boxes[t]; }, fallback);
    auto seen = torch::zeros({1, Ha, Wa});
    for (const auto& b : boxes) seen.narrow(1, b.y0, b.h).narrow(2, b.x0, b.w).fill_(1);
    // Where a weight reached (the rest of a window holds the fallback too).
    const auto reached = windowed.narrow(0, 0, 1) != -1.0f;
    CHECK(reached.sum().item<int64_t>() > 100);
    CHECK((reached <= (seen > 0.5)).all().item<bool>());
    CHECK((windowed - whole).abs().masked_select(reached.expand({3, Ha, Wa})).max().item<float>() <
          1e-6f);
    // Texels no window reaches take the fallback, not the weighted mean.
    CHECK((windowed.masked_select((seen < 0.5).expand({3, Ha, Wa})) == -1.0f).all().item<bool>());
}

TEST_CASE("fuse_frames: frames shifted by whole pixels, added as they are, equal the samplers'") {
    // Three 24x20 frames shifted by whole pixels (two of them partly off a 30x26 atlas) and one
    // by a fraction (the samplers either way), whole and over windows.
    torch::manual_seed(5);
    const int64_t T = 4, H = 20, W = 24, Ha = 26, Wa = 30;
    auto src = torch::rand({T, 3, H, W});
    auto weight = torch::rand({T, 1, H, W}) + 0.1;
    const double shifts[T][2] = {{3, 2}, {-4, 1}, {8, 9}, {2.5, 1}};
    std::vector<torch::Tensor> mats;
    for (const auto& s : shifts) mats.push_back(translation(s[0], s[1]));
    const auto to_atlas = torch::stack(mats).to(torch::kFloat32);
    auto fuse = [&](bool copies, bool windows) {
        return fuse_frames(
            to_atlas, Ha, Wa, [&](int64_t t) { return src[t]; },
            [&](int64_t t) { return weight[t]; }, {},
            windows ? std::function<TexelBox(int64_t)>([&](int64_t t) {
                return TexelBox{int64_t(t), 2, 20, 15};
            })
                    : std::function<TexelBox(int64_t)>(),
            windows ? torch::full({3, Ha, Wa}, -1.0f) : torch::Tensor(), copies);
    };
    for (bool windows : {false, true}) {
        const auto copied = fuse(true, windows), sampled = fuse(false, windows);
        CHECK((copied - sampled).abs().max().item<float>() < 1e-5f);
    }
    // The copies are the frames' own pixels: one frame alone comes back as itself.
    const auto one = fuse_frames(
        to_atlas.narrow(0, 0, 1), Ha, Wa, [&](int64_t) { return src[0]; },
        [&](int64_t) { return weight[0]; });
    CHECK((one.narrow(1, 2, H).narrow(2, 3, W) - src[0]).abs().max().item<float>() < 1e-6f);
}

TEST_CASE("fuse_frames: each frame sampled over its footprint equals the whole atlas's samples") {
    // Four 24x20 frames under homographies (one with perspective, one partly off the atlas, one
    // wholly off it) into a 60x44 atlas.
    torch::manual_seed(6);
    const int64_t T = 4, H = 20, W = 24, Ha = 44, Wa = 60;
    auto src = torch::rand({T, 3, H, W});
    auto weight = torch::rand({T, 1, H, W}) + 0.1;
    auto persp = translation(20.3, 9.7);
    persp[2][0] = 0.002, persp[2][1] = -0.001, persp[0][1] = 0.05;
    const auto to_atlas = torch::stack({translation(3.25, 2.5), persp, translation(-10.6, 30.2),
                                        translation(100.0, 5.0)})
                              .to(torch::kFloat32);
    auto fuse = [&](bool shortcuts) {
        return fuse_frames(
            to_atlas, Ha, Wa, [&](int64_t t) { return src[t]; },
            [&](int64_t t) { return weight[t]; }, {}, {}, {}, shortcuts);
    };
    const auto quick = fuse(true), reference = fuse(false);
    CHECK((quick - reference).abs().max().item<float>() < 1e-6f);
    // The frames are summed in two parts, one a core: the same sums on one thread.
    const int threads = at::get_num_threads();
    at::set_num_threads(1);
    const auto one_thread = fuse(true), one_thread_ref = fuse(false);
    at::set_num_threads(2);
    const auto two_threads = fuse(true);
    at::set_num_threads(threads);
    CHECK(torch::equal(one_thread, quick));
    CHECK(torch::equal(two_threads, quick));
    CHECK(torch::equal(one_thread_ref, reference));
}

TEST_CASE("sharpness_weight is (r + 1/2)^-4") {
    const auto r = torch::rand({1000}) * 60.0;
    const auto w = sharpness_weight(r), ref = (r.to(torch::kFloat64) + 0.5).pow(-4.0);
    CHECK(((w.to(torch::kFloat64) - ref).abs() / ref).max().item<double>() < 1e-6);
    CHECK(sharpness_weight(torch::zeros({1})).item<float>() == 16.0f);
}
