#pragma once
// Shared helpers for the test suites: scratch folders, running the CLI, small test images.
#include <nlohmann/json.hpp>

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "io/image.h"
#include "util/fs.h"

namespace refocus {
struct FitData;
}

namespace refocus::test {

// A fresh empty folder under the build tree, named after the test.
fs::path scratch_dir(const std::string& name);

struct RunResult {
    int code = -1;
    std::string output;  // stdout and stderr together
};
// Runs a shell command line and captures its output.
RunResult run(const std::string& command);
// Runs the refocus CLI with the given argument string.
RunResult cli(const std::string& args);

// A deterministic textured RGB test frame (linear light): gradients, a checkerboard, a moving
// disc at (`t` * 3, ...) so that consecutive frames differ.
Image pattern_frame(int w, int h, int t, unsigned seed = 1);

// Writes `frames` as sRGB PNGs `<dir>/frame_%04d.png` (8 or 16 bit).
void write_png_sequence(const fs::path& dir, const std::vector<Image>& frames,
                        bool sixteen = false);

// Max absolute difference.
double max_abs_diff(const Image& a, const Image& b);

// A tiny synth clip with ground truth (8 frames, seed 3) and a project made from its input
// frames, under scratch_dir(name).
struct TinyClip {
    fs::path dir, clip, project;
};
TinyClip make_tiny(const std::string& name, const std::string& scene = "tripod",
                   const std::string& size = "64x36");

// Exports the project's sharp frames as 32-bit EXR under `c.dir / sub` and reads them back.
std::vector<Image> export_sharp(const TinyClip& c, const std::string& sub,
                                std::string* output = nullptr);

// Sets (or, with nullopt, removes: the default applies) a tuning setting in the project's
// project.json, as `fit --set` keeps it; settings that act on the output apply at export.
void set_project_setting(const fs::path& project, const std::string& name,
                         std::optional<double> value);

// A checkpoint.json as builds before checksums wrote it: for tests that edit one by hand to stand
// for an earlier build's (an edited file that keeps them is refused as damaged).
void strip_checksums(nlohmann::json& checkpoint);

// A tiny two-layer FitData (4 frames of 40x24 random colour, radius 1 px, a static camera, a
// 10x8 subject mask at (12, 8)); no flow unless `with_flow` (zero flow, all consistent).
std::shared_ptr<FitData> tiny_two_layer_data(unsigned seed, bool with_flow = false);

}  // namespace refocus::test
