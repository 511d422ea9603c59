// Refocus Studio: the window loop, the project actions and the side panel's tabs. The menus and
// prompts are in studio_menu.cpp, each panel in its own *_panel.cpp, the test script in
// studio_script.cpp.
#include "studio.h"

#include "key_taps.h"

#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include <algorithm>
#include <cstdio>

#include "edit_menu.h"
#include "io/image_file.h"
#include "layout.h"
#include "log_panel.h"
#include "studio_app.h"
#include "studio_script.h"
#include "util/error.h"

namespace refocus {

Studio::Studio(GLFWwindow* window, GLFWwindow* offscreen, const StudioOptions& opts)
    : m_window(window), m_opts(opts) {
    m_ctx.worker = std::make_unique<FitWorker>();
    const char* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    m_ctx.renderer = std::make_unique<ViewRenderer>(*m_ctx.worker, offscreen, r ? r : "");
    if (opts.remember_layout) m_ctx.layout = load_layout();
    m_atlas.set_edits(&m_ctx.doc.edits());
}

Studio::~Studio() {
    if (m_autosave.valid()) m_autosave.wait();
    if (m_opts.remember_layout) {
        glfwGetWindowSize(m_window, &m_ctx.layout.window_w, &m_ctx.layout.window_h);
        save_layout(m_ctx.layout);
    }
    m_ctx.renderer.reset();  // it asks the worker for frames: it goes first
    m_ctx.worker.reset();    // checkpoints a running fit
    release_viewer(m_viewer);
}

void Studio::after_open() {
    m_ctx.source = std::make_unique<FrameSource>(m_ctx.doc.project().dir.string());
    m_ctx.worker->open(m_ctx.doc.project());
    m_atlas.set_edits(&m_ctx.doc.edits());
    m_ctx.frame = std::clamp(m_ctx.frame, 0, m_ctx.source->frames() - 1);
    m_ctx.renderer->open(m_ctx.doc.project().dir.string(), m_ctx.source->frames(),
                         m_ctx.source->width());
    m_viewer.a.shown = m_viewer.b.shown = nullptr;
    m_ctx.view.reset();
    m_ctx.depth.reset();
    m_ctx.scene = ViewScene{};
    m_ctx.depth_requested = false;
    m_ctx.atlas_version = m_ctx.edit_version = -1;
    m_ctx.in_frame = m_ctx.out_frame = -1;
    m_ctx.view_dirty = m_viewer.slice.dirty = true;
    m_ctx.view_current = false;
    reset_export_panel(m_export, m_ctx);
    load_fit_panel(m_fit, m_ctx.doc.project());
    glfwSetWindowTitle(m_window, ("Refocus Studio - " + m_ctx.doc.project().dir.string()).c_str());
}

void Studio::open_project(const std::string& path) {
    if (m_ctx.busy_with_files()) throw Error("wait until the project being copied or made is done");
    if (is_project_path(path)) {
        m_ctx.doc.open(path);
        after_open();
        return;
    }
    // A plain clip: make a project beside it, named after it.
    fs::path clip = fs::absolute(path);
    if (!fs::exists(clip)) throw Error(file_error(path, "no such file or folder"));
    fs::path dir = clip.parent_path() / (clip.stem().string() + "_refocus");
    for (int i = 2; fs::exists(dir) && !is_project_path(dir.string()); ++i)
        dir = clip.parent_path() / (clip.stem().string() + "_refocus" + std::to_string(i));
    if (is_project_path(dir.string())) {
        m_ctx.doc.open(dir.string());
        after_open();
    } else {
        new_project(clip.string(), dir.string());
    }
}

void Studio::new_project(const std::string& clip, const std::string& dir) {
    // Ingesting decodes every frame into the EXR cache: minutes for a long clip, so it runs on
    // the worker with a progress bar; the project opens when it is done.
    if (m_ctx.busy_with_files()) throw Error("a project is already being copied or made");
    if (clip.empty() || dir.empty()) throw Error("give a clip and a new project folder");
    m_ctx.worker->stop();
    m_ctx.ingest_dir = fs::absolute(dir).string();
    FitWorker* w = m_ctx.worker.get();
    m_ctx.worker->post("ingest " + clip, [w, clip, dir](FitEngine*, const Project&) {
        try {
            Project p = create_project(clip, dir, {},
                                       [w](int i, int n) { w->set_job_progress(double(i) / n); });
            w->post_result("ingested:" + p.dir.string());
        } catch (const std::exception& e) {
            w->post_result(std::string("ingest failed:") + e.what());
        }
    });
}

void Studio::save() {
    if (!m_ctx.doc.is_open()) throw Error("no project is open");
    m_ctx.doc.save();
    m_ctx.info = "saved " + m_ctx.doc.project().project_file().string();
}

void Studio::save_as(const std::string& dir) {
    // The copy holds the frame cache (gigabytes for a long clip): it runs on the worker with a
    // progress bar, and the document moves to the copy when it is done (poll_results).
    if (!m_ctx.doc.is_open()) throw Error("no project is open");
    if (m_ctx.busy_with_files()) throw Error("a project is already being copied or made");
    const fs::path to = m_ctx.doc.save_as_target(dir);
    m_ctx.worker->stop();
    m_ctx.save_as_dir = to.string();
    FitWorker* w = m_ctx.worker.get();
    const fs::path from = m_ctx.doc.project().dir;
    m_ctx.worker->post("save as " + to.string(), [w, from, to](FitEngine*, const Project&) {
        try {
            StudioDoc::copy_project_files(from, to, [w](int i, int n) {
                w->set_job_progress(n > 0 ? double(i) / n : 1.0);
                return !w->cancelled();
            });
            w->post_result("copied:" + to.string());
        } catch (const std::exception& e) {
            w->post_result(std::string("save as failed:") + e.what());
        }
    });
}

void Studio::request_close() {
    if (m_ctx.doc.dirty())
        ask_unsaved(DialogState::Pending::Quit);
    else
        m_quit = true;
}

void Studio::screenshot(const std::string& path) {
    int w, h;
    glfwGetFramebufferSize(m_window, &w, &h);
    std::vector<unsigned char> px(static_cast<size_t>(w) * h * 4);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadBuffer(GL_BACK);
    glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, px.data());
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c)
                img.at(x, y, c) = px[(static_cast<size_t>(h - 1 - y) * w + x) * 4 + c] / 255.0f;
    write_image_file(path, img, PixelFormat::Png8, false);
    int ww, wh;
    glfwGetWindowSize(m_window, &ww, &wh);
    const float s = ww > 0 ? float(w) / ww : 1.0f;
    const ViewerState& v = m_viewer;
    nlohmann::json meta = {{"window", {w, h}},
                           {"frame", m_ctx.frame},
                           {"mode", v.mode->name},
                           {"image_rect", {v.img_x * s, v.img_y * s, v.img_w * s, v.img_h * s}},
                           {"longest_frame_ms", m_ctx.times.longest_frame_ms},
                           {"longest_frame_during_fit_ms", m_ctx.times.longest_fit_frame_ms},
                           {"longest_busy_frame_ms", m_ctx.times.longest_busy_frame_ms}};
    write_file_atomic(path + ".json", meta.dump(2));
}

void Studio::end_frame_timing() {
    FrameTimes& t = m_ctx.times;
    const double ms = (glfwGetTime() - t.frame_start) * 1000.0;
    if (++t.frames_drawn <= 5) return;  // start-up: fonts, shader compilation
    t.longest_frame_ms = std::max(t.longest_frame_ms, ms);
    const bool fitting = m_ctx.worker->status().state == FitWorker::State::Fitting;
    if (fitting) t.longest_fit_frame_ms = std::max(t.longest_fit_frame_ms, ms);
    if (fitting || m_timeline.playing || m_export.running) {
        t.longest_busy_frame_ms = std::max(t.longest_busy_frame_ms, ms);
        ++t.busy_frames;
    }
}

void Studio::poll_results() {
    if (!m_export.running && !m_ctx.busy_with_files()) return;
    auto r = m_ctx.worker->take_result();
    if (!r) return;
    if (r->rfind("copied:", 0) == 0) {
        m_ctx.save_as_dir.clear();
        m_ctx.guarded([&] {
            m_ctx.doc.finish_save_as(r->substr(7));
            after_open();
            m_ctx.info = "saved as " + m_ctx.doc.project().dir.string();
        });
    } else if (r->rfind("save as failed:", 0) == 0) {
        m_ctx.save_as_dir.clear();
        after_open();  // the worker was stopped for the copy: reopen the project as it was
        m_ctx.error = r->substr(15);
    } else if (r->rfind("ingested:", 0) == 0) {
        m_ctx.ingest_dir.clear();
        m_ctx.guarded([&] {
            m_ctx.doc.open(r->substr(9));
            after_open();
        });
    } else if (r->rfind("ingest failed:", 0) == 0) {
        m_ctx.ingest_dir.clear();
        m_ctx.error = r->substr(14);
    } else {
        m_export.running = false;
        m_export.result = *r;
        m_ctx.info = *r;
    }
}

void Studio::draw_side_panel() {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const Layout::Rect r =
        m_ctx.layout.side(vp->WorkPos.x, vp->WorkPos.y, vp->WorkSize.x, vp->WorkSize.y);
    ImGui::SetNextWindowPos(ImVec2(r.x, r.y));
    ImGui::SetNextWindowSize(ImVec2(r.w, r.h));
    ImGui::Begin("Panel", nullptr,
                 ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                     ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoSavedSettings);
    if (ImGui::BeginTabBar("tabs")) {
        if (ImGui::BeginTabItem("Fit")) {
            draw_fit_panel(m_fit, m_ctx);
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Focus")) {
            draw_focus_panel(m_focus, m_viewer, m_ctx);
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Export")) {
            draw_export_panel(m_export, m_ctx);
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Log")) {
            draw_log_panel(m_ctx);
            ImGui::EndTabItem();
        }
        ImGui::EndTabBar();
    }
    ImGui::End();
}

// The line along the window's bottom: what just happened, the fit's state, the renderer. It has
// its own strip, so a message never moves the panels' widgets.
void Studio::draw_status_line() {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const Layout::Rect r =
        m_ctx.layout.status(vp->WorkPos.x, vp->WorkPos.y, vp->WorkSize.x, vp->WorkSize.y);
    ImGui::SetNextWindowPos(ImVec2(r.x, r.y));
    ImGui::SetNextWindowSize(ImVec2(r.w, r.h));
    ImGui::PushStyleVar(ImGuiStyleVar_WindowPadding, ImVec2(8, 4));
    ImGui::Begin("##status", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoSavedSettings |
                     ImGuiWindowFlags_NoBringToFrontOnFocus | ImGuiWindowFlags_NoFocusOnAppearing);
    const FitWorker::Status st = m_ctx.worker->status();
    ImGui::TextDisabled("%s", state_name(st.state));
    if (m_ctx.source) {
        ImGui::SameLine();
        const int mode = wanted_modes(m_viewer)[0];
        ImGui::TextDisabled("| %s | cached %d/%d | proxy %s | preview: %s", m_viewer.mode->label,
                            m_ctx.renderer->cached_frames(mode), m_ctx.source->frames(),
                            m_ctx.renderer->proxy_name().c_str(),
                            m_ctx.renderer->backend_name().c_str());
    }
    if (!m_ctx.info.empty()) {
        ImGui::SameLine();
        ImGui::TextUnformatted(("| " + m_ctx.info).c_str());
        if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", m_ctx.info.c_str());
    }
    ImGui::End();
    ImGui::PopStyleVar();
}

void Studio::step_to_key(int dir) {
    int best = -1;
    for (const auto& l : focus_lanes())
        for (const Keyframe& k : (m_ctx.doc.focus().*(l.lane)).keys)
            if ((dir > 0 ? k.frame > m_ctx.frame : k.frame < m_ctx.frame) &&
                (best < 0 || (dir > 0 ? k.frame < best : k.frame > best)))
                best = k.frame;
    if (best >= 0) set_frame(best);
}

// Editors' transport keys: Space, J/K/L, ←/→ by a frame, Home/End, ↑/↓ to the previous/next
// keyframe, I/O for the in and out points, Alt+X clears them.
void Studio::handle_transport_keys() {
    const ImGuiIO& io = ImGui::GetIO();
    // A tap between two frames counts too (key_taps.h); a press both see is one press.
    auto pressed = [](int key) { return ImGui::IsKeyPressed(key, false) || key_tapped(key); };
    if (pressed(GLFW_KEY_SPACE)) toggle_playback(m_timeline);
    if (pressed(GLFW_KEY_L)) shuttle(m_timeline, 1);
    if (pressed(GLFW_KEY_J)) shuttle(m_timeline, -1);
    if (pressed(GLFW_KEY_K)) shuttle(m_timeline, 0);
    if (ImGui::IsKeyPressed(GLFW_KEY_LEFT)) set_frame(m_ctx.frame - 1);
    if (ImGui::IsKeyPressed(GLFW_KEY_RIGHT)) set_frame(m_ctx.frame + 1);
    if (ImGui::IsKeyPressed(GLFW_KEY_HOME, false)) set_frame(m_ctx.first_frame());
    if (ImGui::IsKeyPressed(GLFW_KEY_END, false)) set_frame(m_ctx.last_frame());
    if (ImGui::IsKeyPressed(GLFW_KEY_UP)) step_to_key(-1);
    if (ImGui::IsKeyPressed(GLFW_KEY_DOWN)) step_to_key(1);
    if (ImGui::IsKeyPressed(GLFW_KEY_I, false)) set_in_point(m_ctx, m_ctx.frame);
    if (ImGui::IsKeyPressed(GLFW_KEY_O, false)) set_out_point(m_ctx, m_ctx.frame);
    if (io.KeyAlt && ImGui::IsKeyPressed(GLFW_KEY_X, false)) m_ctx.in_frame = m_ctx.out_frame = -1;
}

// Shortcuts outside text fields: Ctrl+S / Ctrl+Shift+S / Ctrl+O / Ctrl+N / Ctrl+Q, Tab for the
// atlas editor, the view modes' keys, and the transport keys.
void Studio::handle_keys() {
    ImGuiIO& io = ImGui::GetIO();
    // A text field or a dialog (a prompt, the file browser) has the keys.
    if (io.WantTextInput || ImGui::IsPopupOpen("", ImGuiPopupFlags_AnyPopupId)) return;
    const bool ctrl = io.KeyCtrl;
    if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_S)) {
        if (io.KeyShift)
            m_dialogs.show_save_as = true;
        else
            m_ctx.guarded([&] { save(); });
    }
    if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_O)) m_dialogs.show_open = true;
    if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_N)) m_dialogs.show_new = true;
    if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_Q)) request_close();
    if (!ctrl && ImGui::IsKeyPressed(GLFW_KEY_TAB)) m_viewer.show_atlas = !m_viewer.show_atlas;
    if (!ctrl)
        for (const ViewModeInfo& m : view_modes())
            if (m.key && ImGui::IsKeyPressed(m.key)) set_mode(m);
    if (m_ctx.source && !m_viewer.show_atlas && !ctrl) handle_transport_keys();
}

void Studio::frame() {
    m_ctx.times.frame_start = glfwGetTime();
    handle_keys();
    handle_edit_keys(m_ctx, m_viewer.show_atlas);
    if (glfwWindowShouldClose(m_window) && !m_quit) {
        glfwSetWindowShouldClose(m_window, 0);
        request_close();
    }
    const int before = m_ctx.frame;
    advance_playback(m_timeline, m_ctx);
    if (!m_timeline.playing && before != m_ctx.frame) m_ctx.playback = PlaybackStats{};
    poll_fit_output(m_viewer, m_atlas, m_ctx, m_timeline.playing);
    poll_results();
    draw_menu();
    if (auto click = draw_viewer(m_viewer, m_atlas, m_ctx)) {
        if (click->pick == ViewerState::Pick::Focus)
            m_ctx.guarded([&] { focus_at_pixel(m_ctx.frame, click->x, click->y); });
        if (click->pick == ViewerState::Pick::Track)
            m_ctx.guarded([&] { track_pixel(m_ctx.frame, click->x, click->y); });
    }
    draw_timeline(m_timeline, m_ctx);
    draw_side_panel();
    draw_status_line();
    drag_splitters(m_ctx.layout);
    draw_modals();
    autosave();
    clear_key_taps();
}

// The autosave's files are written on a thread of their own (an edit layer of a 4K atlas is
// tens of MB); the next one waits until the last one is written.
void Studio::autosave() {
    if (m_autosave.valid()) {
        if (m_autosave.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
        m_ctx.guarded([&] { m_autosave.get(); });  // a failed write goes to the error dialog
    }
    if (!m_ctx.doc.is_open()) return;
    m_ctx.guarded([&] {
        if (auto job = m_ctx.doc.take_autosave(glfwGetTime())) {
            m_autosave = std::async(std::launch::async, std::move(job));
            m_ctx.info = "autosaved";
        }
    });
}

// ---- the window ----

int run_studio(const StudioOptions& opts) {
    glfwSetErrorCallback([](int code, const char* msg) {
        std::fprintf(stderr, "refocus-studio: GLFW error %d: %s\n", code, msg);
    });
    if (!glfwInit()) throw Error("cannot initialise GLFW (no display? run under Xvfb)");
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_RESIZABLE, GLFW_TRUE);
    Layout remembered = opts.remember_layout ? load_layout() : Layout{};
    const int win_w = opts.size_given || !opts.remember_layout ? opts.width : remembered.window_w;
    const int win_h = opts.size_given || !opts.remember_layout ? opts.height : remembered.window_h;
    GLFWwindow* window = glfwCreateWindow(win_w, win_h, "Refocus Studio", nullptr, nullptr);
    if (!window) {
        glfwTerminate();
        throw Error("cannot create an OpenGL 3.3 window");
    }
    glfwSetWindowSizeLimits(window, 800, 500, GLFW_DONT_CARE, GLFW_DONT_CARE);
    // The viewer's renderer draws on a context of its own, in a window never shown.
    glfwWindowHint(GLFW_VISIBLE, GLFW_FALSE);
    GLFWwindow* offscreen = glfwCreateWindow(16, 16, "Refocus preview", nullptr, nullptr);
    glfwDefaultWindowHints();
    glfwMakeContextCurrent(window);
    glfwSwapInterval(opts.script.empty() && opts.exit_after < 0 ? 1 : 0);

    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGui::GetIO().IniFilename = nullptr;
    // Space is the transport's, never a widget's "activate" (keyboard navigation stays off).
    ImGui::GetIO().ConfigFlags &= ~ImGuiConfigFlags_NavEnableKeyboard;
    ImGui::StyleColorsDark();
    ImGui_ImplGlfw_InitForOpenGL(window, true);
    install_key_taps(window);  // after ImGui's callbacks, which it chains to
    ImGui_ImplOpenGL3_Init("#version 330 core");

    int code = 0;
    {
        Studio studio(window, offscreen, opts);
        // Clips or projects dropped on the window open in the next frame, as File > Open does.
        glfwSetWindowUserPointer(window, &studio);
        glfwSetDropCallback(window, [](GLFWwindow* w, int n, const char** paths) {
            static_cast<Studio*>(glfwGetWindowUserPointer(w))
                ->drop(std::vector<std::string>(paths, paths + n));
        });
        std::unique_ptr<StudioScript> script;
        if (!opts.script.empty()) {
            script = std::make_unique<StudioScript>(opts.script);
            // Scripts do not hover: park the pointer in an empty corner (no tooltips in shots).
            glfwSetCursorPos(window, opts.width - 2, opts.height - 2);
        }
        if (!opts.open_path.empty()) {
            try {
                studio.open_project(opts.open_path);
                studio.set_frame(opts.start_frame);
            } catch (const std::exception& e) {
                if (opts.exit_after >= 0 || script) {
                    std::fprintf(stderr, "refocus-studio: error: %s\n", e.what());
                    code = 1;
                    glfwSetWindowShouldClose(window, 1);
                } else {
                    studio.set_error_public(e.what());
                }
            }
        }
        int rendered = 0;
        const double opened_at = glfwGetTime();
        while (code == 0 && !studio.want_close()) {
            if (glfwGetWindowAttrib(window, GLFW_ICONIFIED)) {
                glfwWaitEventsTimeout(0.1);  // minimised: sleep instead of drawing
                continue;
            }
            glfwPollEvents();
            ImGui_ImplOpenGL3_NewFrame();
            ImGui_ImplGlfw_NewFrame();
            ImGui::NewFrame();
            studio.frame();
            ImGui::Render();
            int fbw, fbh;
            glfwGetFramebufferSize(window, &fbw, &fbh);
            glViewport(0, 0, fbw, fbh);
            glClearColor(0.08f, 0.08f, 0.09f, 1.0f);
            glClear(GL_COLOR_BUFFER_BIT);
            ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
            studio.end_frame_timing();
            ++rendered;
            if (script) {
                // Script steps run after the frame is drawn, so a screenshot shows it.
                int rc = script->advance(studio);
                if (rc >= 0) {
                    code = rc;
                    break;
                }
            }
            // --exit-after counts frames drawn once the viewer has its picture (a loaded machine
            // can take longer than a few frames), so a screenshot shows what a user would see;
            // after 30 s it counts every frame.
            if (rendered > 0 && !studio.viewer_has_picture() && !opts.open_path.empty() &&
                glfwGetTime() - opened_at < 30.0)
                rendered = 0;
            if (opts.exit_after >= 0 && rendered >= opts.exit_after) {
                if (!opts.screenshot.empty()) studio.screenshot(opts.screenshot);
                break;
            }
            glfwSwapBuffers(window);
        }
        glfwSetDropCallback(window, nullptr);  // the studio goes at the end of this block
    }
    ImGui_ImplOpenGL3_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
    if (offscreen) glfwDestroyWindow(offscreen);
    glfwDestroyWindow(window);
    glfwTerminate();
    return code;
}

}  // namespace refocus
