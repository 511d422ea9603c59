#pragma once
// What the studio's panels share: the open document, the fit worker, the input frames, the GLSL
// preview, the playhead and the fit's output at the playhead. Each panel keeps its own state in
// its own struct (fit_panel.h, focus_panel.h, ...) and reads or changes this one.
#include <cstdint>
#include <exception>
#include <memory>
#include <optional>
#include <set>
#include <string>

#include "frame_source.h"
#include "layout.h"
#include "view_renderer.h"
#include "studio/document.h"
#include "studio/fit_worker.h"

namespace refocus {

// Measured UI frame times (ms), shown in the Log panel and written by the script's "stats".
// "Busy" frames are those drawn while a fit, playback or an export runs: the UI must stay under
// 50 ms a frame then (the renders and the fit run on threads of their own).
struct FrameTimes {
    double frame_start = 0.0;
    double longest_frame_ms = 0.0, longest_fit_frame_ms = 0.0, longest_busy_frame_ms = 0.0;
    int frames_drawn = 0, busy_frames = 0;
};

// What playback showed: the playhead's steps and the pictures on screen meanwhile.
struct PlaybackStats {
    int played = 0;               // playhead steps while playing
    std::set<uint64_t> pictures;  // hashes of the distinct pictures shown while playing
};

struct StudioContext {
    StudioDoc doc;
    std::unique_ptr<FitWorker> worker;
    std::unique_ptr<FrameSource> source;     // the input frames; null until a project is open
    std::unique_ptr<ViewRenderer> renderer;  // the viewer's pictures, off the UI thread
    Layout layout;

    int frame = 0;                      // the playhead
    int in_frame = -1, out_frame = -1;  // in and out points (-1: the clip's ends)

    // The fit's layers at the playhead, from the picture the viewer shows.
    std::shared_ptr<const FitWorker::ViewFrame> view;
    std::shared_ptr<const DepthModel> depth;
    ViewScene scene;             // as last posted to the renderer
    int64_t atlas_version = -1;  // the fit's atlases last asked for
    int64_t edit_version = -1;   // the edited atlases last posted
    double last_refresh_request = -1e9;
    bool depth_requested = false;
    bool view_dirty = true;     // the scene changed: post it to the renderer again
    bool view_current = false;  // the viewer shows the playhead's pictures for the newest scene
    PlaybackStats playback;

    std::string info, error;  // the status line; the error dialog
    // Jobs that copy or make a project on the worker; the project is not usable meanwhile.
    std::string ingest_dir;   // the project a running ingest creates
    std::string save_as_dir;  // the folder a running Save As copies the project to
    FrameTimes times;

    void set_frame(int t) {
        if (!source) return;
        const int n = source->frames();
        frame = ((t % n) + n) % n;
        view_current = false;
    }
    bool busy_with_files() const { return !ingest_dir.empty() || !save_as_dir.empty(); }
    bool view_at_playhead() const { return view && view->t == frame; }
    int first_frame() const { return in_frame >= 0 ? in_frame : 0; }
    int last_frame() const {
        return out_frame >= 0 ? out_frame : (source ? source->frames() - 1 : 0);
    }
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
