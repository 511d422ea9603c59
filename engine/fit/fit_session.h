#pragma once
// A project's fit: its settings (project.json "fit" section), its checkpoint folder, and the
// export of its results. Shared by `refocus fit`, `refocus export`, the studio and the benches.
#include <functional>
#include <memory>
#include <string>

#include "fit/fit_engine.h"
#include "fit/fit_setup.h"
#include "project/project.h"

namespace refocus {

struct ProjectEdits;  // edit/atlas_edit.h

fs::path fit_dir(const Project& project);

struct FitSettings {
    FitOptions fit;
    FitSetupOptions setup;
};
// Reads project.json's "fit" section (throws naming the field when it is malformed).
FitSettings read_fit_settings(const Project& project);
// Writes the settings and the engine's status into the "fit" section and saves project.json.
void write_fit_settings(Project& project, const FitSettings& s, const FitSnapshot* snap);

// Rebuilds the data and loads the latest checkpoint: a fitted project ready to render/export.
std::unique_ptr<FitEngine> open_fitted(const Project& project, PrepareLog& log);

// What `refocus export --what` can write.
enum class ExportPass { Sharp, Reblur, Atlas, Alpha, Coc, Uv, Refocus, Depth };
// sharp|reblur|atlas|alpha|coc|uv|refocus|depth
ExportPass parse_export_pass(const std::string& name);
const char* export_pass_name(ExportPass p);

// Writes one pass. Sequences go to `out` (a folder) as <what>_%04d.<ext> from 0; mp4 to `out`
// (a file). `progress(done, total)` may return false to cancel (what was written is removed).
// Returns the files written. `edits` (the project's atlas edits, may be null) show in the atlas
// and in every rendered frame (sharp, reblur): paper Fig. 1.
std::vector<std::string> export_pass(FitEngine& engine, ExportPass pass, const std::string& format,
                                     const std::string& out, double fps,
                                     const std::function<bool(int, int)>& progress = {},
                                     const ProjectEdits* edits = nullptr);

// Any pass, including those that need the project (edit/): Refocus (the refocused frames: the
// project's "focus" section, edit/focus.h, through the preview's CPU twin with <project>/depth,
// built and saved when missing or stale) and Depth (EXR only, 1 channel: the visible surface's
// inverse depth, the foreground where alpha > 1/2; edit/depth.h). Other passes go to the
// overload above with the project's fps.
std::vector<std::string> export_pass(FitEngine& engine, const Project& project, ExportPass pass,
                                     const std::string& format, const std::string& out,
                                     const std::function<bool(int, int)>& progress = {});

}  // namespace refocus
