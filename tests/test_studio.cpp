// refocus-studio opens a project headless (Xvfb) and shows the frame at the playhead.
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include "io/image_file.h"
#include "project/project.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

#ifdef REFOCUS_STUDIO
TEST_CASE("studio renders frame N of a project into its viewer") {
    if (run("command -v xvfb-run").code != 0) {
        MESSAGE("xvfb-run not installed: skipping");
        return;
    }
    fs::path dir = scratch_dir("studio_open");
    std::vector<Image> frames;
    for (int i = 0; i < 6; ++i) frames.push_back(pattern_frame(64, 36, i));
    write_png_sequence(dir / "seq", frames);
    Project p = create_project((dir / "seq").string(), dir / "proj", {});
    const fs::path shot = dir / "shot.png";
    RunResult r = run("xvfb-run -a -s '-screen 0 800x600x24' " + std::string(REFOCUS_STUDIO) + " '" +
                      (dir / "proj").string() + "' --size 800x600 --frame 4 --screenshot '" +
                      shot.string() + "' --exit-after 4");
    INFO(r.output);
    REQUIRE(r.code == 0);
    REQUIRE(fs::exists(shot));
    auto meta = nlohmann::json::parse(read_text_file(shot.string() + ".json"));
    CHECK(meta["frame"] == 4);
    const double x0 = meta["image_rect"][0], y0 = meta["image_rect"][1];
    const double w = meta["image_rect"][2], h = meta["image_rect"][3];
    CHECK(w > 64 * 5);  // fitted to the window: magnified
    Image screen = read_image_file(shot.string(), false).image;
    const Image& expect = frames[4];
    const Image& other = frames[0];
    int matched = 0, total = 0, differs_from_frame0 = 0;
    for (int y = 1; y < 36; y += 5)
        for (int x = 1; x < 64; x += 7) {
            int sx = int(x0 + (x + 0.5) * w / 64), sy = int(y0 + (y + 0.5) * h / 36);
            bool ok = true, diff0 = false;
            for (int c = 0; c < 3; ++c) {
                int got = int(std::lround(screen.at(sx, sy, c) * 255));
                ok &= std::abs(got - int(linear_to_srgb8(expect.at(x, y, c)))) <= 2;
                diff0 |= std::abs(got - int(linear_to_srgb8(other.at(x, y, c)))) > 2;
            }
            matched += ok;
            differs_from_frame0 += diff0;
            ++total;
        }
    CHECK(matched == total);
    CHECK(differs_from_frame0 > 0);  // it really shows frame 4, not frame 0
}

TEST_CASE("studio reports a bad project path and exits non-zero") {
    if (run("command -v xvfb-run").code != 0) return;
    fs::path dir = scratch_dir("studio_bad");
    RunResult r = run("xvfb-run -a " + std::string(REFOCUS_STUDIO) + " '" + (dir / "missing.mp4").string() +
                      "' --exit-after 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("missing.mp4") != std::string::npos);
}
#endif
