// Long shots as overlapping windows (session/windows.h): how a clip is cut, the cross-fade's
// weights, `new --first/--last`, and a batch's stitched export against the windows' own frames.
#include <doctest/doctest.h>

#include <cmath>
#include <fstream>

#include "io/image_file.h"
#include "session/windows.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("plan_windows: as few equal windows as cover the clip, each overlap as asked") {
    for (auto [frames, window, overlap, n] :
         {std::tuple{600, 240, 16, 3}, std::tuple{240, 240, 16, 1}, std::tuple{241, 240, 16, 2},
          std::tuple{8, 6, 2, 2}, std::tuple{1000, 100, 50, 19}}) {
        CAPTURE(frames);
        CAPTURE(window);
        const auto w = plan_windows(frames, window, overlap);
        REQUIRE(int(w.size()) == n);
        CHECK(w.front().first == 0);
        CHECK(w.back().last == frames - 1);
        for (size_t k = 0; k < w.size(); ++k) {
            CHECK(w[k].last - w[k].first + 1 <= window);
            if (k > 0) CHECK(w[k - 1].last - w[k].first + 1 == overlap);
        }
        // Every frame: weights that sum to 1, in at most two windows, and a window's weight
        // falls across the overlap as the next one's rises.
        for (int t = 0; t < frames; ++t) {
            const auto ww = window_weights(w, t);
            REQUIRE(ww.size() <= 2);
            float sum = 0;
            for (auto [k, x] : ww) sum += x, CHECK(x > 0.0f);
            CHECK(sum == doctest::Approx(1.0));
        }
    }
    CHECK(plan_windows(600, 240, 16)[1].first == 195);
    CHECK_THROWS_WITH(plan_windows(100, 10, 6), doctest::Contains("window >= 2 x overlap"));
}

TEST_CASE("new --first/--last: a range of the clip becomes frames 0..") {
    const TinyClip c = make_tiny("windows_range", "pan");
    const fs::path p = c.dir / "range";
    auto r = cli("new '" + (c.clip / "input_%04d.png").string() + "' -o '" + p.string() +
                 "' --first 2 --last 4");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("(frames 2..4)") != std::string::npos);
    const Project whole = Project::load(c.project), part = Project::load(p);
    REQUIRE(part.frames == 3);
    for (int t = 0; t < 3; ++t)
        CHECK(read_image_file(part.frame_path(t).string()).image.pixels ==
              read_image_file(whole.frame_path(t + 2).string()).image.pixels);
    r = cli("new '" + (c.clip / "input_%04d.png").string() + "' -o '" + (c.dir / "bad").string() +
            "' --first 3 --last 99");
    CHECK(r.code != 0);
    CHECK(r.output.find("are not inside the clip's") != std::string::npos);
    CHECK(!fs::exists(c.dir / "bad"));
}

TEST_CASE("batch: a shot over its window is fitted as windows; export cross-fades them") {
    const fs::path root = scratch_dir("windows_batch");
    REQUIRE(cli("synth --scene pan -o '" + (root / "pan").string() + "' --size 64x36 --frames 8")
                .code == 0);
    {
        std::ofstream f(root / "shots.json");
        f << R"({"shots": [{"name": "long", "clip": "pan/input_%04d.png", "project": "p/long",
                 "iters": 20, "window": 6, "overlap": 2,
                 "exports": [{"what": "sharp", "format": "exr", "out": "out/long"}]}]})";
    }
    auto r = cli("batch run '" + (root / "shots.json").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const WindowedShot shot = WindowedShot::load(root / "p/long");
    REQUIRE(shot.windows.size() == 2);
    // Each window's own frames, then the stitched ones: a single window's frame as it is, the
    // overlap's the weighted sum (in linear light; half-float EXR, so to its precision).
    std::vector<std::vector<Image>> own(2);
    for (int k = 0; k < 2; ++k) {
        const fs::path d = root / ("own" + std::to_string(k));
        r = cli("export '" + (root / "p/long" / shot.windows[k].dir).string() +
                "' --what sharp --format exr --out '" + d.string() + "'");
        REQUIRE(r.code == 0);
        for (int t = 0; t <= shot.windows[k].last - shot.windows[k].first; ++t)
            own[k].push_back(read_image_file(ClipWriter::sequence_path(d.string(), "sharp", t,
                                                                       ClipFormat::ExrHalf))
                                 .image);
    }
    for (int t = 0; t < 8; ++t) {
        CAPTURE(t);
        const Image got =
            read_image_file(ClipWriter::sequence_path((root / "out/long").string(), "sharp", t,
                                                      ClipFormat::ExrHalf))
                .image;
        double worst = 0;
        const auto ww = window_weights(shot.windows, t);
        for (size_t i = 0; i < got.pixels.size(); ++i) {
            double want = 0;
            for (auto [k, x] : ww) want += x * own[k][t - shot.windows[k].first].pixels[i];
            worst = std::max(worst, std::abs(want - got.pixels[i]) / (std::abs(want) + 1e-2));
        }
        CHECK(worst < 2e-3);
        if (t == 3 || t == 4) CHECK(ww.size() == 2);
    }
    // The shot's folder is not a project: the message says what it is.
    r = cli("fit '" + (root / "p/long").string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("is a shot fitted as windows") != std::string::npos);
    r = cli("export '" + (root / "p/long").string() + "' --what atlas --out '" +
            (root / "atl").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("each window's own") != std::string::npos);
}
