#pragma once
// A long shot fitted as overlapping windows of its frames, each window a project of its own
// (docs/method.md, Batches: long shots). <shot>/windows.json names the clip, its frame count and
// each window's frames and folder (windows/wNN); export stitches the windows' frames with a
// linear cross-fade over each overlap.
#include <functional>
#include <string>
#include <vector>

#include "session/fit_session.h"

namespace refocus {

struct ShotWindow {
    int first = 0, last = 0;  // frames of the clip, inclusive
    std::string dir;          // relative to the shot's folder: "windows/w00"
};

struct WindowedShot {
    static constexpr const char* kFileName = "windows.json";
    fs::path dir;
    std::string clip;
    int frames = 0, window = 0, overlap = 0;
    std::vector<ShotWindow> windows;

    static bool is_windowed(const fs::path& dir);
    // Throws refocus::Error naming windows.json and the field.
    static WindowedShot load(const fs::path& dir);
    void save() const;  // atomic
};

// `frames` frames as windows of at most `window` frames that overlap by `overlap` (window >=
// 2 * overlap, so that no frame is in more than two): as few windows as cover the clip, of equal
// length (the last one may be shorter), each overlap exactly `overlap` frames.
std::vector<ShotWindow> plan_windows(int frames, int window, int overlap);

// The windows that hold frame t and their weights (sum 1): one window at weight 1, or two
// cross-fading linearly over their overlap (the later one's weight (t - a + 1) / (n + 1) at the
// overlap's t - a-th frame of n).
std::vector<std::pair<int, float>> window_weights(const std::vector<ShotWindow>& w, int t);

// Writes pass `pass` of a windowed shot as export_pass writes a project's (every window must be
// fitted): frames 0..frames-1 of the clip, each from its window, cross-faded in the overlaps in
// linear light, with each window's edits. The atlas and uv passes are each window's own and are
// refused (export them from the window's project).
std::vector<std::string> export_windowed(const WindowedShot& shot, ExportPass pass,
                                         const std::string& format, const std::string& out,
                                         const std::function<bool(int, int)>& progress = {});

}  // namespace refocus
