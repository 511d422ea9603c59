#pragma once
// project.json: what a Refocus project holds. Paths inside are relative to the project folder
// (the source clip may be absolute when it lies outside). Sections owned by later stages (fit,
// focus, edits) are kept as JSON and written back untouched by code that does not know them.
#include <nlohmann/json.hpp>

#include <functional>
#include <string>
#include <vector>

#include "io/clip.h"
#include "util/fs.h"

namespace refocus {

// Budgets a fit accepts (CLI flags and project.json's "fit" section): a week, 10^8 steps.
constexpr double kMaxFitMinutes = 7 * 24 * 60.0;
constexpr long long kMaxFitIters = 100000000;
constexpr int kMaxFitBatch = 4096;
constexpr long long kMaxFitSeed = (1LL << 53) - 1;  // exact in a JSON double
// Below this a clip has no room for optical flow (OpenCV's DIS refuses frames under 12 px).
constexpr int kMinClipSize = 12;

struct Project {
    static constexpr int kVersion = 1;
    static constexpr const char* kFileName = "project.json";

    fs::path dir;  // the project folder (not stored)
    int version = kVersion;
    std::string name;
    std::string source;       // the clip it was made from, as stored
    std::string source_kind;  // "video" or "sequence"
    int width = 0, height = 0, frames = 0;
    double fps = 24.0;
    std::string frame_pattern;                           // relative: "frames/frame_%04d.exr"
    std::string source_format;                           // "uint8", "uint16", "half", "float"
    nlohmann::json sections = nlohmann::json::object();  // later stages' data

    fs::path project_file() const { return dir / kFileName; }
    fs::path frame_path(int index) const;
    // Cached frame as linear RGB.
    Image read_frame(int index) const;

    nlohmann::json to_json() const;
    // Validates every field; throws refocus::Error naming the file and the field.
    static Project from_json(const nlohmann::json& j, const fs::path& dir,
                             const std::string& label);
    static Project load(const fs::path& dir_or_file);
    // Atomic write of project.json (the previous file stays intact on failure).
    void save() const;
    // Saves, but every section not named in `own` is taken from the project.json on disk when
    // there is one: other writers (the studio's fit thread writes "fit", its document "focus"
    // and "edits") may have updated theirs since this object was loaded. Serialised within the
    // process. The merged sections are kept in this object.
    void save_merged(const std::vector<std::string>& own);
};

// A stored number of project.json's "fit" section, its flag and its bounds.
struct FitFieldBound {
    const char* key;   // "batch"
    const char* flag;  // "--batch"
    double lo, hi;
    bool integer;
};
const std::vector<FitFieldBound>& fit_field_bounds();
const FitFieldBound& fit_field_bound(const std::string& key);
// The "fit" section's numbers and strings against their bounds; refocus::Error naming `label`,
// the field and the flag that sets it.
void check_fit_section(const nlohmann::json& fit, const std::string& label);
// An integer flag's text for fit field `key` ("batch", "seed", "iters") against the same bound;
// refocus::Error "--batch must be an integer in 0..4096 (got '99999')".
long long checked_fit_flag(const std::string& key, const std::string& text);

// Is `path` a project folder (or its project.json)?
bool is_project_path(const std::string& path);

// Ingests `clip` into a new project at `dir` (created; must be empty or absent): the frames
// become a linear EXR cache that later stages read quickly. `progress(i, n)` is called per frame.
Project create_project(const std::string& clip, const fs::path& dir, const ClipReadOptions& opts,
                       const std::function<void(int, int)>& progress = {});

}  // namespace refocus
