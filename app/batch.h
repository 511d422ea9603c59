#pragma once
// A shot list's shots and what each project holds, shared by `refocus batch` here
// (app/cmd_batch.cpp) and on Slurm (app/cmd_batch_slurm.cpp).
#include <csignal>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "session/windows.h"
#include "util/fs.h"

namespace refocus::batch {

struct ShotExport {
    std::string what, format, out;
};

struct Shot {
    int row = 0;  // 1-based, as a person counts
    std::string name, clip, project, preset = "fast", coc, mask;
    double minutes = 0;
    long long iters = 0;
    std::vector<std::string> set;  // name=value
    std::vector<ShotExport> exports;
    int window = 240, overlap = 16;  // a longer shot is fitted as windows (0: never)
    int first = 0, last = -1;        // a window's frames of the clip (-1: the whole clip)
    // The shot's windows once known (windows_of): empty for a shot fitted whole.
    mutable std::shared_ptr<std::vector<ShotWindow>> windows;
    // The clip's header once read (clip_info_of): a video is decoded to count its frames.
    mutable std::shared_ptr<ClipInfo> clip_info;
};

// What a shot's project holds: its fit's state and figures, read from project.json.
struct ShotState {
    bool project = false, fitted = false;  // fitted: done, to this shot's budget and preset
    bool checkpoint = false;
    bool resumable = false;  // an unfinished fit of this shot's budget and preset: --resume
    long long steps = 0;
    double reblur = 0.0 / 0.0;
    int exports_done = 0;
};

struct Outcome {
    std::string state = "pending";
    double seconds = 0;
    long peak_kb = 0;
};

// The whole list, checked before anything runs: every error names the row and the field.
std::vector<Shot> read_shots(const fs::path& list);
ShotState state_of(const Shot& s);
// A shot over its window length is fitted as overlapping windows, each a shot of its own
// (without exports) in <project>/windows/wNN; `export` stitches them. Known from windows.json
// once the shot was started, else from the clip's frame count. Empty: fitted whole.
const std::vector<ShotWindow>& windows_of(const Shot& s);
// The clip's size and frame count, read once per shot.
const ClipInfo& clip_info_of(const Shot& s);
std::vector<Shot> window_shots(const Shot& s);
// The `refocus` commands that finish the shot: what its project lacks.
std::vector<std::vector<std::string>> steps_of(const Shot& s, const ShotState& st);
std::string joined(const std::vector<std::string>& v);
// "done", "fitted", "partial", "ingested" or "to do", from the project alone.
std::string project_state(const Shot& s);

// Runs the shot's remaining steps as child processes with `threads` threads each, their output
// appended to <logs>/<name>.log, a line per step on stdout (under `print`). Stops before the
// next step once `*stop` is set (the step running finishes as it would on SIGTERM).
// `window` >= 0: only that window's steps (a Slurm array task; the log <name>_wNN.log).
Outcome run_shot(const Shot& s, const fs::path& logs, int threads, std::mutex& print,
                 const volatile std::sig_atomic_t* stop, int window = -1);

// The folder beside the list where `batch` keeps its logs.
inline fs::path logs_folder(const fs::path& list) {
    return list.parent_path() / "batch_logs";
}

// A shot's wall time (whole minutes) and memory (MB) on a 2-core node: what `submit` asks of
// Slurm (docs/method.md, Batches).
struct ShotCost {
    int minutes = 0;
    int mem_mb = 0;
};
ShotCost shot_cost(const Shot& s, int width, int height, int frames);

// Slurm (app/cmd_batch_slurm.cpp). `args` are the command line after "batch".
int batch_submit(const fs::path& list, const std::vector<Shot>& shots, int argc, char** argv);
int batch_shot(const fs::path& list, const std::vector<Shot>& shots, int argc, char** argv);
// Per shot, what Slurm says of the list's last submission ("" where it says nothing: no
// submission, no squeue, or the task has left the queue).
std::vector<std::string> slurm_states(const fs::path& list, const std::vector<Shot>& shots);

}  // namespace refocus::batch
