#pragma once
// Helpers of the robustness suites: the CLI under a timeout, tiny clips and projects, a small
// disk, loading a project in a forked child.
#include <doctest/doctest.h>

#include <string>
#include <vector>

#include "test_util.h"
#include "util/fs.h"

namespace refocus::robust {

using test::RunResult;

// Single-quoted for sh.
std::string q(const std::string& s);
// The CLI under a timeout: 124 is a hang, >= 128 a signal (crash).
RunResult cli_t(const std::string& args, int seconds = 60);
int count_lines_with(const std::string& text, const std::string& what);
// A failure is one "error:" line naming `file`, no raw library exception, no crash.
void expect_clean_error(const RunResult& r, const std::string& file,
                        const std::string& problem = "");
std::string file_bytes(const fs::path& p);

// A small synthetic clip and its project (48x32, 6 frames).
struct Clip {
    fs::path dir, clip, project;
};
Clip make_clip(const std::string& name, const std::string& size = "48x32");
// One fitted project shared by a suite's export cases (a fit is the costly part); each suite
// names its own, as suites run side by side.
const Clip& fitted(const std::string& name = "robust_fitted");
// An mp4 of a few frames.
fs::path make_mp4(const fs::path& path);

// A tmpfs of `kib` KiB mounted on `dir` for the scope (root only; skipped elsewhere).
struct SmallDisk {
    fs::path dir;
    bool ok = false;
    SmallDisk(const fs::path& d, int kib);
    ~SmallDisk();
    void fill(long keep);  // fills all but `keep` bytes
};

// One "error:" line naming `file`, no raw library exception.
bool one_line_naming(const std::string& out, const std::string& file);

struct Outcome {
    int rc = -1;  // 0 loaded, 1 refused, 124 hang, 128 + signal crash
    std::string out;
};
// Project::load (what `refocus info` does) in a forked child under a timeout.
Outcome load_in_child(const fs::path& dir, int seconds);
std::vector<std::string> stray_temporaries(const fs::path& dir);

}  // namespace refocus::robust
