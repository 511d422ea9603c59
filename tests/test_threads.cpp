// Per-frame work on the cores (util/threads.h): every index once, errors brought back, the
// preparation's flows and masks the same whatever thread made them, and the flow's files written
// on a thread of their own.
#include <doctest/doctest.h>

#include <ATen/Parallel.h>

#include "prep_fixtures.h"
#include "prepare/prepare.h"
#include "project/project.h"
#include "test_util.h"
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

TEST_CASE("prep folder: the flow's files written while the masks are made read back as saved") {
    // The fit writes the flow's files on a thread of its own beside the later stages
    // (PrepareOptions::flow_ready), and save_prepare then writes the rest.
    const fs::path root = test::scratch_dir("prepare_flow_early");
    const int w = 64, h = 36, n = 4;
    std::vector<Image> frames;
    std::vector<cv::Mat> truth;
    disc_clip(w, h, n, frames, truth);
    test::write_png_sequence(root / "clip", frames, true);
    const Project project = create_project((root / "clip").string(), root / "proj", {});
    std::vector<Image> cached;
    for (int t = 0; t < n; ++t) cached.push_back(project.read_frame(t));
    PrepareOptions opts;
    int calls = 0;
    opts.flow_ready = [&](const ClipFlow& flow) {
        ++calls;
        CHECK_FALSE(has_prepare(project));
        save_prepare_flow(project, flow, w, h);
    };
    PrepareLog log;
    const PrepareResult r = prepare_clip(cached, opts, log);
    CHECK(calls == 1);
    CHECK_FALSE(has_prepare(project));  // the marker waits for the rest
    save_prepare(project, r, true);
    REQUIRE(has_prepare(project));
    const PrepareResult l = load_prepare(project);
    REQUIRE(l.flow.fwd.size() == size_t(n - 1));
    for (int t = 0; t + 1 < n; ++t) {
        CHECK(test::max_abs_diff(l.flow.fwd[t], r.flow.fwd[t]) == 0.0);
        CHECK(test::max_abs_diff(l.flow.bwd[t], r.flow.bwd[t]) == 0.0);
        CHECK(test::max_abs_diff(l.flow.fwd_valid[t], r.flow.fwd_valid[t]) == 0.0);
    }
    for (int t = 0; t < n; ++t) CHECK(test::max_abs_diff(l.masks[t], r.masks[t]) < 1.0 / 255);
    // An error in the writer comes back from prepare_clip.
    opts.flow_ready = [](const ClipFlow&) { throw Error("prep/flow_fwd_0000.exr: disk full"); };
    PrepareLog log2;
    CHECK_THROWS_WITH_AS(prepare_clip(cached, opts, log2), "prep/flow_fwd_0000.exr: disk full",
                         Error);
}
