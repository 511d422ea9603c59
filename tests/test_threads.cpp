// Per-frame work on the cores (util/threads.h): every index once, errors brought back, and the
// preparation's flows and masks the same whatever thread made them.
#include <doctest/doctest.h>

#include <ATen/Parallel.h>

#include "prep_fixtures.h"
#include "prepare/prepare.h"
#include "util/error.h"
#include "util/threads.h"

using namespace refocus;
using namespace refocus::test::prep;

TEST_CASE("threads: every index once, on its thread; the first error comes back") {
    std::vector<int> seen(23, 0), by(23, -1);
    for_each_on_threads(23, 3, [&](int i, int k) { seen[i] += 1, by[i] = k; });
    for (int i = 0; i < 23; ++i) {
        CHECK(seen[i] == 1);
        CHECK(by[i] == i % 3);
    }
    CHECK_THROWS_WITH_AS(for_each_on_threads(10, 2,
                                             [](int i, int) {
                                                 if (i == 5) throw Error("frame 5 is damaged");
                                             }),
                         "frame 5 is damaged", Error);
}

TEST_CASE("flow and masks: the same on one thread as on two") {
    // Pairs and frames run on the cores with their own estimators: a frame's results must not
    // depend on the thread that made them.
    const int w = 128, h = 72, n = 6;
    std::vector<Image> frames;
    std::vector<cv::Mat> truth;
    disc_clip(w, h, n, frames, truth);
    const int threads = at::get_num_threads();
    auto run = [&](int k, ClipFlow& flow, std::vector<Image>& masks) {
        at::set_num_threads(k);
        flow = compute_clip_flow(frames);
        PrepareLog log;
        const CameraMotion cm = estimate_camera_motion(frames, &flow, MotionOptions{}, log);
        masks = automatic_masks(frames, &flow, cm);
    };
    ClipFlow f1, f2;
    std::vector<Image> m1, m2;
    run(1, f1, m1);
    run(2, f2, m2);
    at::set_num_threads(threads);
    REQUIRE(f1.fwd.size() == size_t(n - 1));
    for (int t = 0; t + 1 < n; ++t) {
        CHECK(f1.fwd[t].pixels == f2.fwd[t].pixels);
        CHECK(f1.bwd_valid[t].pixels == f2.bwd_valid[t].pixels);
    }
    for (int t = 0; t < n; ++t) CHECK(m1[t].pixels == m2[t].pixels);
}
