#pragma once
// Refocus Studio's state and actions. The menus, panels and the test script (--script) all go
// through the same action methods, so what a script checks is what a user's click does.
#include <nlohmann/json.hpp>

#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "atlas_panel.h"
#include "studio/fit_worker.h"
#include "frame_source.h"
#include "gl_preview.h"
#include "studio.h"
#include "studio/document.h"

struct GLFWwindow;

namespace refocus {

enum class ViewMode { Input, Sharp, Refocused, Split, Radius, Depth, Alpha };
const char* view_mode_name(ViewMode m);
ViewMode parse_view_mode(const std::string& name);

// One animated focus parameter as the UI lists it.
struct LaneInfo {
    const char* name;
    Lane FocusTrack::*lane;
    double min, max;
    const char* format;
};
const std::vector<LaneInfo>& focus_lanes();

class Studio {
public:
    Studio(GLFWwindow* window, const StudioOptions& opts);
    ~Studio();

    // One UI frame: menus, panels, viewer. Returns false when the window should close.
    void frame();
    bool want_close() const { return m_quit; }
    void request_close();  // asks about unsaved changes first

    // ---- actions (menus, panels and scripts) ----
    void open_project(const std::string& path);
    void new_project(const std::string& clip, const std::string& dir);
    void save();
    void save_as(const std::string& dir);
    void start_fit(bool resume);
    void set_frame(int t);
    void set_key(const std::string& lane, int frame, double value, Easing e);
    void focus_at_pixel(int frame, int x, int y);  // click-to-focus
    void track_pixel(int frame, int x, int y);     // focus tracking of the atlas point there
    void start_export(const nlohmann::json& request);  // see export panel / script "export"
    void screenshot(const std::string& path);

    void set_error_public(const std::string& e) { m_error = e; }
    void end_frame_timing();
    int frame_index() const { return m_frame; }
    FitWorker& worker() { return *m_worker; }
    StudioDoc& doc() { return m_doc; }
    AtlasPanel& atlas_panel() { return m_atlas_panel; }
    void set_mode(ViewMode m) { m_mode = m; m_show_atlas = false; m_view_dirty = true; }
    bool view_current() const;  // the viewer shows the playhead frame with the newest state
    bool exporting() const { return m_exporting; }
    bool ingesting() const { return !m_ingest_dir.empty(); }
    bool saving_as() const { return !m_save_as_dir.empty(); }
    bool busy_with_files() const { return ingesting() || saving_as(); }
    const std::string& last_error() const { return m_error; }
    const std::string& export_result() const { return m_export_result; }

    // Measured UI frame times (ms) for the report.
    double longest_frame_ms() const { return m_longest_frame_ms; }
    double longest_frame_during_fit_ms() const { return m_longest_fit_frame_ms; }
    double last_preview_ms() const { return m_last_preview_ms; }

private:
    friend class StudioScript;
    // panels
    void draw_menu();
    void draw_viewer();
    void draw_timeline();
    void draw_side_panel();
    void draw_fit_tab();
    void draw_focus_tab();
    void draw_export_tab();
    void draw_log_tab();
    void poll_results();  // export outcomes, ingested clips
    void draw_modals();
    // viewer plumbing
    void poll_worker();
    void refresh_view();
    Image view_image(ViewMode mode);
    Image preview_image(bool refocus);
    void upload(unsigned& tex, const Image& linear_rgb, int& w, int& h);
    void rebuild_time_slice();
    void poll_time_slice();
    bool image_pixel(float sx, float sy, int& x, int& y) const;
    void set_error(const std::string& e) { m_error = e; }
    void after_open();
    // Runs an action; its error goes to the error dialog instead of ending the program.
    template <class F>
    void guarded(F&& f) {
        try {
            f();
        } catch (const std::exception& e) {
            set_error(e.what());
        }
    }

    GLFWwindow* m_window;
    StudioOptions m_opts;
    StudioDoc m_doc;
    std::unique_ptr<FitWorker> m_worker;
    std::unique_ptr<FrameSource> m_source;  // the input frames
    std::unique_ptr<GlPreview> m_gl;
    std::string m_gl_error;
    AtlasPanel m_atlas_panel;

    // playhead / view
    int m_frame = 0;
    bool m_playing = false;
    double m_play_clock = 0.0;
    ViewMode m_mode = ViewMode::Input, m_split_a = ViewMode::Input, m_split_b = ViewMode::Refocused;
    float m_split = 0.5f;
    float m_zoom = 0.0f;
    bool m_show_atlas = false;
    bool m_time_slice = false;
    int m_slice_row = -1;
    bool m_pick_focus = false, m_pick_track = false;
    Easing m_new_key_easing = Easing::EaseInOut;

    // what the viewer shows
    std::optional<FitWorker::ViewFrame> m_view;
    int m_requested_frame = -1;
    int64_t m_atlas_version = -1, m_edit_version = -1;
    double m_last_refresh_request = -1e9;
    bool m_view_dirty = true;
    unsigned m_tex = 0, m_slice_tex = 0;
    int m_tex_w = 0, m_tex_h = 0, m_slice_w = 0, m_slice_h = 0;
    std::shared_ptr<const DepthModel> m_depth;
    bool m_depth_requested = false;
    bool m_slice_dirty = true;
    struct SliceJob {
        std::mutex mutex;
        bool done = false;
        Image image;  // linear, width x frames
        std::string key;
    };
    std::shared_ptr<SliceJob> m_slice_job;
    std::string m_slice_key, m_slice_label = "input";
    Image m_slice_image;  // what the slice texture shows (linear RGB; x → column, y → frame)
    // image rectangle last drawn (screen px) for clicks and screenshots
    float m_img_x = 0, m_img_y = 0, m_img_w = 0, m_img_h = 0;

    // fit panel
    int m_preset = 0;
    float m_budget_minutes = 5.0f;
    int m_budget_iters = 0;
    bool m_use_iters = false;
    int m_seed = 1;
    char m_coc_path[1024] = {0}, m_mask_path[1024] = {0};

    // export panel
    bool m_exp_pass[8] = {true, true, false, false, false, false, false, false};
    int m_exp_format = 0;
    int m_exp_first = 0, m_exp_last = -1;
    char m_exp_out[1024] = {0};
    bool m_exporting = false;
    std::string m_export_result;
    std::string m_ingest_dir;  // the project a running ingest creates
    std::string m_save_as_dir; // the folder a running Save As copies the project to

    // modals / prompts
    std::string m_error, m_info;
    bool m_quit = false;
    enum class Pending { None, Open, New, Close, Quit } m_pending = Pending::None;
    std::string m_pending_path, m_pending_clip;
    bool m_show_open = false, m_show_new = false, m_show_save_as = false, m_show_unsaved = false;
    char m_path_buf[1024] = {0}, m_clip_buf[1024] = {0};

    // timing
    double m_frame_start = 0.0;
    double m_longest_frame_ms = 0.0, m_longest_fit_frame_ms = 0.0;
    double m_last_preview_ms = 0.0;  // the last GLSL preview render, read-back included
    int m_frames_drawn = 0;
};

}  // namespace refocus
