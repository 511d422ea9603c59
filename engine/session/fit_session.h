#pragma once
// A project's fit: its settings (project.json "fit" section), its checkpoint folder, and the
// export of its results. Shared by `refocus fit`, `refocus export`, the studio and the benches.
#include <functional>
#include <limits>
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
// Sets the user's settings on both parts (settings.h) and applies those of their fields.
void use_settings(FitSettings& s, const Settings& settings);
// Reads project.json's "fit" section (throws naming the field when it is malformed).
FitSettings read_fit_settings(const Project& project);
// Writes the settings and the engine's status into the "fit" section and saves project.json.
void write_fit_settings(Project& project, const FitSettings& s, const FitSnapshot* snap);

// The options of a model whose set-up the project's checkpoint replaces (export, the studio,
// `fit --resume`): no ECC alignment and no fused atlases where the checkpoint holds the
// geometry. Only the engine sees them; project.json keeps `fit` as it was.
FitOptions restoring_options(const Project& project, FitOptions fit);
// Rebuilds the data and loads the latest checkpoint for reading (FitEngine::CheckpointUse::Read:
// a step or a save reads the rest): a fitted project ready to render and export.
std::unique_ptr<FitEngine> open_fitted(const Project& project, PrepareLog& log);

// What `refocus export --what` can write.
enum class ExportPass {
    Sharp,
    Reblur,
    Atlas,
    Alpha,
    Coc,
    Uv,
    Refocus,
    Depth,
    Confidence,
    Flow,
    Parallax
};
// sharp|reblur|atlas|alpha|coc|uv|refocus|depth|confidence|flow
ExportPass parse_export_pass(const std::string& name);
// Passes of values rather than pictures (coc px, atlas coordinates, inverse depth, flow px):
// float EXR only.
bool is_data_pass(ExportPass p);
const char* export_pass_name(ExportPass p);

struct FocusTrack;  // edit/focus.h

// Where an export's plate is the shot rather than the fit (fit/confidence.h), as shares of the
// exported frames' pixels: `unexplained`, the fit cannot explain the region (it falls back);
// `unseen`, no frame saw it sharp (fit.trust_seen_px: its detail would be deconvolution alone);
// `not_sharper`, no other frame saw it sharper (fit.sharper_view_px: the atlas holds no detail
// the shot lacks); `in_focus`, nothing is blurred there (the shot needs nothing). All weighted by
// how much.
struct FallbackShare {
    double unexplained = 0, unseen = 0, not_sharper = 0, in_focus = 0;
    int frames = 0;
    int worst_frame = -1;    // the frame with the largest unexplained share
    double worst_share = 0;  // ... and that share
    // How well the fit explains the clip (FitEngine::residual_rms, model_trust): NaN unmeasured.
    double residual_rms = std::numeric_limits<double>::quiet_NaN(), noise = 0, trust = 0;
    bool deconvolves = false;     // fit.trusted_blur_px set: trust opens γ too
    std::string summary() const;  // one line for the terminal
};

struct ExportOptions {
    double fps = 24.0;
    // The project: needed by Refocus (its "focus" section, edit/focus.h, and <project>/depth,
    // built and saved when missing or stale) and Depth.
    const Project* project = nullptr;
    const ProjectEdits* edits = nullptr;     // atlas edits (paper Fig. 1); null: none
    const FocusTrack* focus = nullptr;       // focus keys to use instead of the project's section
    int first = 0, last = -1;                // frames first..last (-1: the last frame)
    std::function<bool(int, int)> progress;  // (done, total); false cancels
    FallbackShare* fallback = nullptr;       // filled by the passes made from the plate
};

// Refuses (refocus::Error naming `target`) an export target that is, or lies inside, the
// project's own files (project.json, fit/, frames/, prep/, edits/, depth/), or that is an input of
// the fit: the source clip (a sequence's whole folder) and the --coc / --mask files' folders.
void check_export_target(const Project& p, const fs::path& target);

// Writes one pass. Sequences go to `out` (a folder) as <what>_%04d.<ext> numbered from 0 (the
// range's first frame is file 0); mp4 to `out` (a file). A cancelled or failed export removes
// what it wrote: files are complete or absent. Edits show in the atlas and in every rendered
// frame (sharp, reblur, refocus). Refocus: the frames through the preview's CPU twin
// (render/preview.h) with the focus keys and the depth model; Depth (EXR only, 1 channel): the
// visible surface's inverse depth, the foreground where alpha > 1/2 (edit/depth.h).
// Confidence (1 channel): 1 where the fit explains the pixel, 0 where the plate falls back to
// the shot (FitEngine::confidence).
// Returns the files written.
std::vector<std::string> export_pass(FitEngine& engine, ExportPass pass, const std::string& format,
                                     const std::string& out, const ExportOptions& opts);

// One pass's frames, one at a time, as export_pass writes them (edits, the fallback, refocus);
// not the atlas. `three_channels`: one-channel passes as grey RGB (mp4).
class PassFrames {
  public:
    PassFrames(FitEngine& engine, ExportPass pass, bool three_channels, const ExportOptions& o);
    ~PassFrames();
    Image frame(int t);

  private:
    struct State;  // the edits' deltas, the focus keys and the depth model
    FitEngine& m_engine;
    ExportPass m_pass;
    bool m_three, m_needs_project = false;
    ExportOptions m_opts;
    std::unique_ptr<State> m;
};
// No export writes a NaN/Inf pixel: refocus::Error naming the pass and frame `t` (-1: none).
void refuse_nonfinite(const Image& img, const std::string& what, int t);
// How export_pass writes a pass: its clip format (data passes as float EXR; refuses a format
// that cannot hold them) and writer options.
ClipFormat pass_clip_format(ExportPass pass, const std::string& format);
ClipWriteOptions pass_write_options(ExportPass pass, double fps);

}  // namespace refocus
