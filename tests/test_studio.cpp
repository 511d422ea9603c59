// refocus-studio opens a project headless (Xvfb) and shows the frame at the playhead; scripted
// sessions drive the whole studio (tests/gui/smoke.json) and its file browser and drops
// (tests/gui/browser.json).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

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
    RunResult r = run("xvfb-run -a -s '-screen 0 800x600x24' " + std::string(REFOCUS_STUDIO) +
                      " '" + (dir / "proj").string() + "' --size 800x600 --frame 4 --screenshot '" +
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
    RunResult r = run("xvfb-run -a " + std::string(REFOCUS_STUDIO) + " '" +
                      (dir / "missing.mp4").string() + "' --exit-after 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("missing.mp4") != std::string::npos);
}

TEST_CASE("scripted studio session: the file browser lists a folder, a drop opens a clip") {
    if (run("command -v xvfb-run").code != 0) {
        MESSAGE("xvfb-run not installed: skipping");
        return;
    }
    // A folder with an image sequence, a project and a video's name (listed, never read).
    fs::path dir = scratch_dir("studio_browser");
    std::vector<Image> frames;
    for (int i = 0; i < 4; ++i) frames.push_back(pattern_frame(48, 32, i));
    write_png_sequence(dir / "seq", frames);
    create_project((dir / "seq").string(), dir / "proj", {});
    write_file_atomic((dir / "clip_a.mp4").string(), "");
    const std::string script = std::string(REFOCUS_SOURCE_DIR) + "/tests/gui/browser.json";
    RunResult r = run("cd '" + dir.string() + "' && XDG_CONFIG_HOME='" + dir.string() +
                      "' xvfb-run -a -s '-screen 0 1280x800x24' " + std::string(REFOCUS_STUDIO) +
                      " --size 1280x800 --script '" + script + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(fs::exists(dir / "browser.png"));
    // The dropped sequence got a project beside it, then the browser's pick opened "proj":
    // both went through File > Open's action, which lists them as recent, newest first.
    CHECK(Project::load(dir / "seq_refocus").frames == 4);
    auto recent = nlohmann::json::parse(read_text_file((dir / "refocus/recent.json").string()));
    REQUIRE(recent.size() == 2);
    CHECK(fs::path(recent[0].get<std::string>()).filename() == "proj");
    CHECK(fs::path(recent[1].get<std::string>()).filename() == "seq_refocus");
}

namespace {
// Strongly red pixels (the smoke script paints a red stroke on the background atlas).
int red_pixels(const Image& img, int x0, int y0, int w, int h) {
    int n = 0;
    for (int y = std::max(0, y0); y < std::min(img.height, y0 + h); ++y)
        for (int x = std::max(0, x0); x < std::min(img.width, x0 + w); ++x)
            n += img.at(x, y, 0) > 0.6f && img.at(x, y, 1) < 0.15f && img.at(x, y, 2) < 0.15f;
    return n;
}
}  // namespace

TEST_CASE("scripted studio session: new, fit, paint, keyframes, export, save, reopen") {
    if (run("command -v xvfb-run").code != 0) {
        MESSAGE("xvfb-run not installed: skipping");
        return;
    }
    fs::path dir = scratch_dir("studio_smoke");
    const std::string script = std::string(REFOCUS_SOURCE_DIR) + "/tests/gui/smoke.json";
    RunResult r = run("cd '" + dir.string() + "' && XDG_CONFIG_HOME='" + dir.string() +
                      "' REFOCUS_SOURCE_DIR='" + REFOCUS_SOURCE_DIR +
                      "' xvfb-run -a -s '-screen 0 1280x800x24' " + std::string(REFOCUS_STUDIO) +
                      " --size 1280x800 --script '" + script + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);

    // Export: frames 0..2 of the sharp plate and of the refocused video, nothing more.
    for (const char* what : {"sharp", "refocus"})
        for (int i = 0; i < 4; ++i) {
            const fs::path f =
                dir / "export" / what / (std::string(what) + "_000" + std::to_string(i) + ".png");
            CHECK_MESSAGE(fs::exists(f) == (i < 3), f.string());
        }
    // The paint on the background atlas shows in the exported sharp frame, not in the input.
    Image sharp = read_image_file((dir / "export/sharp/sharp_0000.png").string()).image;
    Project p = Project::load(dir / "smoke_proj");
    Image input = p.read_frame(0);
    CHECK(red_pixels(sharp, 0, 0, sharp.width, sharp.height) > 200);
    CHECK(red_pixels(input, 0, 0, input.width, input.height) < 20);
    // The time slice of the sharp view (row 31, through the stroke) shows the unsaved paint in
    // the frames, as the viewer and the export do.
    Image slice = read_image_file((dir / "slice_sharp.png").string()).image;
    CHECK(slice.width == sharp.width);
    CHECK(slice.height == p.frames);
    CHECK(red_pixels(slice, 0, 0, slice.width, slice.height) > 10 * p.frames);
    // Refocused frames differ from the sharp plate (aperture 1.5, focus keyed).
    Image refocused = read_image_file((dir / "export/refocus/refocus_0002.png").string()).image;
    Image sharp2 = read_image_file((dir / "export/sharp/sharp_0002.png").string()).image;
    double diff = 0;
    for (size_t i = 0; i < sharp2.pixels.size(); ++i)
        diff += std::abs(sharp2.pixels[i] - refocused.pixels[i]);
    CHECK(diff / sharp2.pixels.size() > 0.005);

    // Saved work: keyframes and edits in the project.
    auto j = nlohmann::json::parse(read_text_file((dir / "smoke_proj/project.json").string()));
    REQUIRE(j.contains("focus"));
    CHECK(j["focus"]["focus"].size() == 2);  // the two click-to-focus keys
    CHECK(fs::exists(dir / "smoke_proj/edits"));
    // Save As (copied on the worker): the copy holds the frames and the work, and the session
    // went on in it (the reopen step opened the copy and found the keys, edits and fit).
    CHECK(fs::exists(dir / "smoke_copy/edits"));
    CHECK(Project::load(dir / "smoke_copy").read_frame(29).width == p.width);
    auto jc = nlohmann::json::parse(read_text_file((dir / "smoke_copy/project.json").string()));
    CHECK(jc["focus"]["focus"].size() == 2);

    // Screenshot of the sharp view at frame 0: the viewer shows the painted stroke.
    auto meta = nlohmann::json::parse(read_text_file((dir / "shot_sharp.png.json").string()));
    CHECK(meta["frame"] == 0);
    CHECK(meta["mode"] == "sharp");
    Image shot = read_image_file((dir / "shot_sharp.png").string(), false).image;
    const int x0 = meta["image_rect"][0], y0 = meta["image_rect"][1];
    const int w = meta["image_rect"][2], h = meta["image_rect"][3];
    CHECK(w > 320);
    CHECK(red_pixels(shot, x0, y0, w, h) > 200);
    // The screen shows the exported frame: sample a grid of the image rectangle.
    int close = 0, total = 0;
    for (int y = 5; y < sharp.height; y += 20)
        for (int x = 5; x < sharp.width; x += 20) {
            const int sx = int(x0 + (x + 0.5) * w / sharp.width),
                      sy = int(y0 + (y + 0.5) * h / sharp.height);
            double d = 0;
            for (int c = 0; c < 3; ++c)
                d +=
                    std::abs(shot.at(sx, sy, c) - linear_to_srgb(sharp.at(x, y, c)));  // shot: sRGB
            close += d / 3 < 0.08;
            ++total;
        }
    CHECK(close > total * 0.9);
    auto stats = nlohmann::json::parse(read_text_file((dir / "stats.json").string()));
    MESSAGE("longest UI frame " << stats["longest_frame_ms"] << " ms, during the fit "
                                << stats["longest_frame_during_fit_ms"] << " ms");

    // Playback of Refocused (30 frames, after the render cache filled) showed distinct pictures,
    // and no UI frame drawn during the fit, the playback or the export took 50 ms or more: the
    // renders run off the UI thread. Both lines are printed for scripts to read.
    int distinct = -1, shown = -1;
    double longest = -1;
    const size_t d = r.output.find(" distinct frames of ");
    REQUIRE(d != std::string::npos);
    const size_t pb = r.output.rfind("playback: ", d);
    REQUIRE(pb != std::string::npos);
    REQUIRE(std::sscanf(r.output.c_str() + pb, "playback: %d distinct frames of %d", &distinct,
                        &shown) == 2);
    const size_t lf = r.output.find("longest UI frame: ");
    REQUIRE(lf != std::string::npos);
    REQUIRE(std::sscanf(r.output.c_str() + lf, "longest UI frame: %lf ms", &longest) == 1);
    MESSAGE("playback: " << distinct << " distinct frames of " << shown << "; longest UI frame "
                         << longest << " ms");
    CHECK(distinct >= 20);
    CHECK(shown >= 30);
    CHECK(longest < 50.0);
}

TEST_CASE("studio killed during a fit offers the autosave on reopen and restores it") {
    if (run("command -v xvfb-run").code != 0) {
        MESSAGE("xvfb-run not installed: skipping");
        return;
    }
    // A tiny project: the crash comes after the first fit step.
    fs::path dir = scratch_dir("studio_crash");
    REQUIRE(cli("synth --scene tripod -o '" + (dir / "clip").string() +
                "' --size 64x48 --frames 6 --seed 2")
                .code == 0);
    REQUIRE(cli("new '" + (dir / "clip" / "input_%04d.png").string() + "' -o '" +
                (dir / "p").string() + "'")
                .code == 0);
    auto studio = [&](const char* script) {
        return run("cd '" + dir.string() + "' && XDG_CONFIG_HOME='" + dir.string() +
                   "' CRASH_PROJECT='" + (dir / "p").string() +
                   "' xvfb-run -a -s '-screen 0 1280x800x24' " + std::string(REFOCUS_STUDIO) +
                   " --size 1280x800 --script '" + REFOCUS_SOURCE_DIR + "/tests/gui/" + script +
                   "'");
    };
    // Keys, an autosave, a fit that rewrites project.json, then SIGKILL.
    RunResult crashed = studio("crash_fit.json");
    INFO(crashed.output);
    REQUIRE(crashed.code != 0);
    REQUIRE(crashed.output.find("{\"crash\":true}") != std::string::npos);
    CHECK(fs::exists(dir / "p/.autosave/project.json"));
    // Reopened: the autosave is offered although project.json is newer, and brings the keys back.
    RunResult reopened = studio("crash_reopen.json");
    INFO(reopened.output);
    CHECK(reopened.code == 0);
}

TEST_CASE("scripted studio session: key moves, undo and redo, the atlas editor leaves no change") {
    if (run("command -v xvfb-run").code != 0) {
        MESSAGE("xvfb-run not installed: skipping");
        return;
    }
    fs::path dir = scratch_dir("studio_keys");
    RunResult r = cli("synth --scene tripod -o '" + (dir / "clip").string() +
                      "' --size 64x36 --frames 6 --seed 2");
    REQUIRE(r.code == 0);
    const std::string script = std::string(REFOCUS_SOURCE_DIR) + "/tests/gui/keys.json";
    r = run("cd '" + dir.string() + "' && XDG_CONFIG_HOME='" + dir.string() + "' KEYS_CLIP='" +
            (dir / "clip/input_%04d.png").string() + "' xvfb-run -a -s '-screen 0 1280x800x24' " +
            std::string(REFOCUS_STUDIO) + " --size 1280x800 --script '" + script + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    // Saved after the last move (0 and 5), before the undo and redo that followed.
    auto j = nlohmann::json::parse(read_text_file((dir / "keys_proj/project.json").string()));
    REQUIRE(j["focus"]["focus"].size() == 2);
    CHECK(j["focus"]["focus"][0]["frame"] == 0);
    CHECK(j["focus"]["focus"][1]["frame"] == 5);
    CHECK(j["focus"]["focus"][1]["easing"] == "ease_in");
    CHECK(fs::exists(dir / "keys.png"));
}
#endif
