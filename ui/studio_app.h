#pragma once
// Refocus Studio: the window's panels over one shared StudioContext. The menus, panels and the
// test script (--script) all go through the same actions, so what a script checks is what a
// user's click does. Each panel's state lives in its own struct beside its drawing code.
#include <nlohmann/json.hpp>

#include <future>
#include <string>
#include <vector>

#include "atlas_panel.h"
#include "export_panel.h"
#include "file_browser.h"
#include "fit_panel.h"
#include "focus_panel.h"
#include "studio.h"
#include "studio_context.h"
#include "timeline_panel.h"
#include "viewer_panel.h"

struct GLFWwindow;

namespace refocus {

// The File menu's prompts, the file browser they open (also from the start screen and the
// export and atlas panels' own), paths dropped on the window, and the question about unsaved
// changes.
struct DialogState {
    bool show_open = false, show_new = false, show_save_as = false, show_unsaved = false;
    enum class Pending {
        None,
        Open,
        New,
        Quit
    } pending = Pending::None;  // after "unsaved changes"
    std::string pending_path, pending_clip;
    char path_buf[1024] = {0}, clip_buf[1024] = {0};
    // What the browser is open for; Cancel goes back to the prompt it was opened from.
    enum class Browse { None, Open, NewClip, NewFolder, SaveAs } browsing = Browse::None;
    bool back_to_prompt = false;
    FileBrowser browser;
    std::vector<std::string> dropped;  // dropped on the window: the first opens next frame
    std::string places_for = "\n";     // the project the browser's places were last set for
};

class Studio {
  public:
    // `offscreen`: a hidden window whose GL context the viewer's renderer takes (may be null).
    Studio(GLFWwindow* window, GLFWwindow* offscreen, const StudioOptions& opts);
    ~Studio();

    // One UI frame: menus, panels, viewer.
    void frame();
    bool want_close() const { return m_quit; }
    void request_close();  // asks about unsaved changes first

    // ---- actions (menus, panels and scripts) ----
    void open_project(const std::string& path);
    void new_project(const std::string& clip, const std::string& dir);
    void save();
    void save_as(const std::string& dir);
    // Paths dropped on the window (GLFW's drop callback, the script's "drop"): the first is
    // opened in the next frame as File > Open would, asking about unsaved changes first.
    void drop(const std::vector<std::string>& paths) { m_dialogs.dropped = paths; }
    void start_fit(bool resume) { refocus::start_fit(m_fit, m_ctx, resume); }
    void set_frame(int t) { m_ctx.set_frame(t); }
    void set_key(const std::string& lane, int frame, double value, Easing e) {
        set_focus_key(m_ctx, lane, frame, value, e);
    }
    void focus_at_pixel(int frame, int x, int y) {
        refocus::focus_at_pixel(m_ctx, m_focus.new_key_easing, frame, x, y);
    }
    void track_pixel(int frame, int x, int y) {
        refocus::track_pixel(m_ctx, m_focus.new_key_easing, frame, x, y);
    }
    void start_export(const nlohmann::json& request) {
        refocus::start_export(m_export, m_ctx, request);
    }
    // Whether the viewer has drawn a picture (frames load off the UI thread).
    bool viewer_has_picture() const { return m_viewer.img_w > 0; }
    void screenshot(const std::string& path);
    void set_mode(const ViewModeInfo& m) { set_view_mode(m_viewer, m_ctx, m); }

    void set_error_public(const std::string& e) { m_ctx.error = e; }
    void end_frame_timing();
    bool view_current() const { return m_ctx.view_current; }  // the playhead, newest scene
    bool playing() const { return m_timeline.playing; }
    void play(bool on) {
        if (on != m_timeline.playing) toggle_playback(m_timeline);
    }
    bool exporting() const { return m_export.running; }
    bool ingesting() const { return !m_ctx.ingest_dir.empty(); }
    bool saving_as() const { return !m_ctx.save_as_dir.empty(); }
    const std::string& last_error() const { return m_ctx.error; }
    const std::string& export_result() const { return m_export.result; }
    const FrameTimes& times() const { return m_ctx.times; }

  private:
    friend class StudioScript;
    void draw_menu();
    void draw_side_panel();
    void draw_modals();
    void draw_path_dialogs();
    void browse(DialogState::Browse what, bool from_prompt, const std::string& dir = {});
    void draw_browser();
    void take_requests();                    // dropped paths, the start screen's buttons
    void ask_open(const std::string& path);  // opens, or asks about unsaved changes first
    void draw_unsaved_dialog();
    void draw_autosave_and_error();
    void ask_unsaved(DialogState::Pending what);
    void handle_keys();
    void handle_transport_keys();
    void draw_status_line();
    void autosave();
    void step_to_key(int direction);  // the playhead to the previous / next keyframe
    void poll_results();              // export outcomes, ingested clips, Save As copies
    void after_open();

    GLFWwindow* m_window;
    StudioOptions m_opts;
    StudioContext m_ctx;  // declared before the panels: they go first when the studio closes
    ViewerState m_viewer;
    TimelineState m_timeline;
    FitPanelState m_fit;
    FocusPanelState m_focus;
    ExportPanelState m_export;
    AtlasPanel m_atlas;
    DialogState m_dialogs;
    bool m_quit = false;
    std::future<void> m_autosave;  // the autosave being written
};

}  // namespace refocus
