#pragma once
// What the studio's panels share: the open document, the fit worker, the input frames, the GLSL
// preview, the playhead and the fit's output at the playhead. Each panel keeps its own state in
// its own struct (fit_panel.h, focus_panel.h, ...) and reads or changes this one.
#include <cstdint>
#include <exception>
#include <memory>
#include <optional>
#include <string>

#include "frame_source.h"
#include "gl_preview.h"
#include "studio/document.h"
#include "studio/fit_worker.h"

namespace refocus {

// Measured UI frame times (ms), shown in the Log panel and written by the script's "stats".
struct FrameTimes {
    double frame_start = 0.0;
    double longest_frame_ms = 0.0, longest_fit_frame_ms = 0.0;
    double last_preview_ms = 0.0;  // the last GLSL preview render, read-back included
    int frames_drawn = 0;
};

// The window's layout: the viewer (or the Atlas panel) top left, the timeline under it, the side
// panel with the Fit, Focus, Export and Log tabs on the right.
constexpr float kSidePanelWidth = 380.0f;
constexpr float kTimelineHeight = 200.0f;

struct StudioContext {
    StudioDoc doc;
    std::unique_ptr<FitWorker> worker;
    std::unique_ptr<FrameSource> source;  // the input frames; null until a project is open
    std::unique_ptr<GlPreview> gl;  // null when the preview failed to start: gl_error says why
    std::string gl_error;

    int frame = 0;  // the playhead

    // The fit's output as the worker last delivered it; the viewer asks for the playhead's.
    std::optional<FitWorker::ViewFrame> view;
    std::shared_ptr<const DepthModel> depth;
    int requested_frame = -1;
    int64_t atlas_version = -1;  // the fit's atlases last asked for
    int64_t edit_version = -1;   // the edited atlases last given to the GLSL preview
    double last_refresh_request = -1e9;
    bool depth_requested = false;
    bool view_dirty = true;  // the viewer must show the playhead's newest state again

    std::string info, error;  // the status line; the error dialog
    // Jobs that copy or make a project on the worker; the project is not usable meanwhile.
    std::string ingest_dir;   // the project a running ingest creates
    std::string save_as_dir;  // the folder a running Save As copies the project to
    FrameTimes times;

    void set_frame(int t) {
        if (!source) return;
        const int n = source->frames();
        frame = ((t % n) + n) % n;
        view_dirty = true;
    }
    bool busy_with_files() const { return !ingest_dir.empty() || !save_as_dir.empty(); }
    bool view_at_playhead() const { return view && view->t == frame; }
    // The artist's atlas edits change this on every stroke, undo or import.
    int64_t edits_version() { return doc.edits().bg.version() + doc.edits().fg.version(); }
    // A change of the focus keys or the edits: the document is unsaved and the view stale.
    void changed() {
        doc.mark_dirty();
        view_dirty = true;
    }

    // Runs an action; its error goes to the error dialog instead of ending the program.
    template <class F>
    void guarded(F&& f) {
        try {
            f();
        } catch (const std::exception& e) {
            error = e.what();
        }
    }
};

}  // namespace refocus
