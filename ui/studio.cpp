// Refocus Studio: the window loop, the menus and the modal prompts. Panels live in
// studio_panels.cpp, the viewer and timeline in studio_view.cpp, the test script in
// studio_script.cpp.
#include "studio.h"

#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "io/image_file.h"
#include "studio_app.h"
#include "studio_script.h"
#include "util/error.h"

namespace refocus {

const char* view_mode_name(ViewMode m) {
    switch (m) {
        case ViewMode::Input: return "input";
        case ViewMode::Sharp: return "sharp";
        case ViewMode::Refocused: return "refocused";
        case ViewMode::Split: return "split";
        case ViewMode::Radius: return "radius";
        case ViewMode::Depth: return "depth";
        case ViewMode::Alpha: return "alpha";
    }
    return "?";
}

ViewMode parse_view_mode(const std::string& n) {
    for (ViewMode m : {ViewMode::Input, ViewMode::Sharp, ViewMode::Refocused, ViewMode::Split,
                       ViewMode::Radius, ViewMode::Depth, ViewMode::Alpha})
        if (n == view_mode_name(m)) return m;
    throw Error("unknown view mode '" + n + "' (input, sharp, refocused, split, radius, depth, alpha)");
}

Studio::Studio(GLFWwindow* window, const StudioOptions& opts)
    : m_window(window), m_opts(opts), m_worker(std::make_unique<FitWorker>()) {
    try {
        m_gl = std::make_unique<GlPreview>();
    } catch (const std::exception& e) {
        m_gl_error = e.what();  // the refocused view says why it is off
    }
    m_atlas_panel.set_edits(&m_doc.edits());
}

Studio::~Studio() {
    m_worker.reset();  // checkpoints a running fit
    if (m_tex) glDeleteTextures(1, &m_tex);
    if (m_slice_tex) glDeleteTextures(1, &m_slice_tex);
}

void Studio::after_open() {
    m_source = std::make_unique<FrameSource>(m_doc.project().dir.string());
    m_worker->open(m_doc.project());
    m_atlas_panel.set_edits(&m_doc.edits());
    m_frame = std::clamp(m_frame, 0, m_source->frames() - 1);
    m_view.reset();
    m_depth.reset();
    m_depth_requested = false;
    m_atlas_version = m_edit_version = -1;
    m_requested_frame = -1;
    m_view_dirty = m_slice_dirty = true;
    m_exp_first = 0;
    m_exp_last = m_source->frames() - 1;
    const FitSettings s = read_fit_settings(m_doc.project());
    const char* presets[] = {"fast", "paper", "perframe"};
    for (int i = 0; i < 3; ++i)
        if (s.fit.preset == presets[i]) m_preset = i;
    if (s.fit.iters > 0 && s.fit.minutes <= 0) {
        m_use_iters = true;
        m_budget_iters = static_cast<int>(s.fit.iters);
    } else if (s.fit.minutes > 0) {
        m_budget_minutes = static_cast<float>(s.fit.minutes);
    }
    m_seed = static_cast<int>(s.fit.seed);
    std::snprintf(m_coc_path, sizeof m_coc_path, "%s", s.setup.coc_path.c_str());
    std::snprintf(m_mask_path, sizeof m_mask_path, "%s", s.setup.mask_path.c_str());
    if (m_exp_out[0] == 0)
        std::snprintf(m_exp_out, sizeof m_exp_out, "%s", (m_doc.project().dir / "export").string().c_str());
    glfwSetWindowTitle(m_window, ("Refocus Studio - " + m_doc.project().dir.string()).c_str());
}

void Studio::open_project(const std::string& path) {
    if (busy_with_files()) throw Error("wait until the project being copied or made is done");
    if (is_project_path(path)) {
        m_doc.open(path);
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
        m_doc.open(dir.string());
        after_open();
    } else {
        new_project(clip.string(), dir.string());
    }
}

void Studio::new_project(const std::string& clip, const std::string& dir) {
    // Ingesting decodes every frame into the EXR cache: minutes for a long clip, so it runs on
    // the worker with a progress bar; the project opens when it is done.
    if (busy_with_files()) throw Error("a project is already being copied or made");
    if (clip.empty() || dir.empty()) throw Error("give a clip and a new project folder");
    m_worker->stop();
    m_ingest_dir = fs::absolute(dir).string();
    FitWorker* w = m_worker.get();
    m_worker->post("ingest " + clip, [w, clip, dir](FitEngine*, const Project&) {
        try {
            Project p = create_project(clip, dir, {}, [w](int i, int n) { w->set_job_progress(double(i) / n); });
            w->post_result("ingested:" + p.dir.string());
        } catch (const std::exception& e) {
            w->post_result(std::string("ingest failed:") + e.what());
        }
    });
}

void Studio::save() {
    if (!m_doc.is_open()) throw Error("no project is open");
    m_doc.save();
    m_info = "saved " + m_doc.project().project_file().string();
}

void Studio::save_as(const std::string& dir) {
    // The copy holds the frame cache (gigabytes for a long clip): it runs on the worker with a
    // progress bar, and the document moves to the copy when it is done (poll_results).
    if (!m_doc.is_open()) throw Error("no project is open");
    if (busy_with_files()) throw Error("a project is already being copied or made");
    const fs::path to = m_doc.save_as_target(dir);
    m_worker->stop();
    m_save_as_dir = to.string();
    FitWorker* w = m_worker.get();
    const fs::path from = m_doc.project().dir;
    m_worker->post("save as " + to.string(), [w, from, to](FitEngine*, const Project&) {
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
    if (m_doc.dirty()) {
        m_pending = Pending::Quit;
        m_show_unsaved = true;
    } else {
        m_quit = true;
    }
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
    nlohmann::json meta = {{"window", {w, h}},
                           {"frame", m_frame},
                           {"mode", view_mode_name(m_mode)},
                           {"image_rect", {m_img_x * s, m_img_y * s, m_img_w * s, m_img_h * s}},
                           {"longest_frame_ms", m_longest_frame_ms},
                           {"longest_frame_during_fit_ms", m_longest_fit_frame_ms}};
    write_file_atomic(path + ".json", meta.dump(2));
}

void Studio::draw_menu() {
    if (!ImGui::BeginMainMenuBar()) return;
    if (ImGui::BeginMenu("File")) {
        const bool idle = !busy_with_files();
        if (ImGui::MenuItem("New from clip...", "Ctrl+N", false, idle)) m_show_new = true;
        if (ImGui::MenuItem("Open...", "Ctrl+O", false, idle)) m_show_open = true;
        if (ImGui::BeginMenu("Open recent", idle)) {
            auto list = recent_projects();
            if (list.empty()) ImGui::MenuItem("(none)", nullptr, false, false);
            for (const auto& r : list)
                if (ImGui::MenuItem(r.c_str())) {
                    if (m_doc.dirty()) {
                        m_pending = Pending::Open;
                        m_pending_path = r;
                        m_show_unsaved = true;
                    } else {
                        guarded([&] { open_project(r); });
                    }
                }
            ImGui::EndMenu();
        }
        if (ImGui::MenuItem("Save", "Ctrl+S", false, m_doc.is_open())) guarded([&] { save(); });
        if (ImGui::MenuItem("Save as...", "Ctrl+Shift+S", false, m_doc.is_open() && idle)) m_show_save_as = true;
        ImGui::Separator();
        if (ImGui::MenuItem("Quit", "Ctrl+Q")) request_close();
        ImGui::EndMenu();
    }
    if (ImGui::BeginMenu("View")) {
        for (ViewMode m : {ViewMode::Input, ViewMode::Sharp, ViewMode::Refocused, ViewMode::Split,
                           ViewMode::Radius, ViewMode::Depth, ViewMode::Alpha})
            if (ImGui::MenuItem(view_mode_name(m), nullptr, m_mode == m && !m_show_atlas)) {
                m_mode = m;
                m_show_atlas = false;
                m_view_dirty = true;
            }
        ImGui::Separator();
        ImGui::MenuItem("Atlas editor", "Tab", &m_show_atlas);
        if (ImGui::MenuItem("Time slice", nullptr, &m_time_slice)) m_slice_dirty = true;
        ImGui::EndMenu();
    }
    const auto st = m_worker->status();
    ImGui::SameLine(ImGui::GetWindowWidth() - 420);
    ImGui::TextDisabled("%s%s  |  fit: %s%s", m_doc.is_open() ? m_doc.project().name.c_str() : "",
                        m_doc.dirty() ? " *" : "", state_name(st.state),
                        st.busy ? ("  |  " + st.busy_what).c_str() : "");
    ImGui::EndMainMenuBar();
}

namespace {
bool path_popup(const char* title, const char* prompt, char* buf, size_t n, const char* ok) {
    bool go = false;
    if (ImGui::BeginPopupModal(title, nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted(prompt);
        ImGui::SetNextItemWidth(520);
        if (ImGui::IsWindowAppearing()) ImGui::SetKeyboardFocusHere();
        go = ImGui::InputText("##path", buf, n, ImGuiInputTextFlags_EnterReturnsTrue);
        go |= ImGui::Button(ok);
        ImGui::SameLine();
        if (ImGui::Button("Cancel") || go) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    return go;
}
}  // namespace

void Studio::draw_modals() {
    auto open_popup = [](bool& flag, const char* name) {
        if (flag) ImGui::OpenPopup(name);
        flag = false;
    };
    open_popup(m_show_open, "Open project");
    open_popup(m_show_new, "New project");
    open_popup(m_show_save_as, "Save project as");
    open_popup(m_show_unsaved, "Unsaved changes");
    if (path_popup("Open project", "Project folder, or a clip (video, image folder or pattern):",
                   m_path_buf, sizeof m_path_buf, "Open")) {
        if (m_doc.dirty()) {
            m_pending = Pending::Open;
            m_pending_path = m_path_buf;
            m_show_unsaved = true;
        } else {
            guarded([&] { open_project(m_path_buf); });
        }
    }
    if (ImGui::BeginPopupModal("New project", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted("Clip (video file, image folder or printf pattern):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##clip", m_clip_buf, sizeof m_clip_buf);
        ImGui::TextUnformatted("New project folder (created):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##dir", m_path_buf, sizeof m_path_buf);
        if (ImGui::Button("Create")) {
            ImGui::CloseCurrentPopup();
            if (m_doc.dirty()) {
                m_pending = Pending::New;
                m_pending_clip = m_clip_buf;
                m_pending_path = m_path_buf;
                m_show_unsaved = true;
            } else {
                guarded([&] { new_project(m_clip_buf, m_path_buf); });
            }
        }
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    if (path_popup("Save project as", "New project folder (the project, its fit and edits are copied):",
                   m_path_buf, sizeof m_path_buf, "Save"))
        guarded([&] { save_as(m_path_buf); });
    if (ImGui::BeginPopupModal("Unsaved changes", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::Text("%s has unsaved changes (focus keyframes, atlas paint).",
                    m_doc.is_open() ? m_doc.project().name.c_str() : "The project");
        auto proceed = [&] {
            const Pending p = m_pending;
            m_pending = Pending::None;
            if (p == Pending::Quit) m_quit = true;
            if (p == Pending::Open) guarded([&] { open_project(m_pending_path); });
            if (p == Pending::New) guarded([&] { new_project(m_pending_clip, m_pending_path); });
        };
        if (ImGui::Button("Save")) {
            ImGui::CloseCurrentPopup();
            bool ok = true;
            try {
                save();
            } catch (const std::exception& e) {
                ok = false;  // the error shows; nothing is closed
                set_error(e.what());
            }
            if (ok) proceed();
        }
        ImGui::SameLine();
        if (ImGui::Button("Discard")) {
            ImGui::CloseCurrentPopup();
            m_doc.discard_autosave();
            proceed();
        }
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) {
            m_pending = Pending::None;
            ImGui::CloseCurrentPopup();
        }
        ImGui::EndPopup();
    }
    if (m_doc.is_open() && m_doc.has_newer_autosave()) ImGui::OpenPopup("Restore autosave");
    if (ImGui::BeginPopupModal("Restore autosave", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted("This project has autosaved changes newer than its last save\n"
                               "(the studio was closed without saving). Restore them?");
        if (ImGui::Button("Restore")) {
            guarded([&] { m_doc.restore_autosave(); });
            m_view_dirty = true;
            ImGui::CloseCurrentPopup();
        }
        ImGui::SameLine();
        if (ImGui::Button("Discard")) {
            m_doc.discard_autosave();
            ImGui::CloseCurrentPopup();
        }
        ImGui::EndPopup();
    }
    if (!m_error.empty()) ImGui::OpenPopup("Error");
    if (ImGui::BeginPopupModal("Error", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::PushTextWrapPos(600);
        ImGui::TextUnformatted(m_error.c_str());
        ImGui::PopTextWrapPos();
        if (ImGui::Button("OK")) {
            m_error.clear();
            ImGui::CloseCurrentPopup();
        }
        ImGui::EndPopup();
    }
}

void Studio::frame() {
    m_frame_start = glfwGetTime();
    ImGuiIO& io = ImGui::GetIO();
    if (!io.WantTextInput) {
        const bool ctrl = io.KeyCtrl;
        if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_S)) {
            if (io.KeyShift) m_show_save_as = true;
            else guarded([&] { save(); });
        }
        if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_O)) m_show_open = true;
        if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_N)) m_show_new = true;
        if (ctrl && ImGui::IsKeyPressed(GLFW_KEY_Q)) request_close();
        if (!ctrl && ImGui::IsKeyPressed(GLFW_KEY_TAB)) m_show_atlas = !m_show_atlas;
        if (m_source && !m_show_atlas) {
            if (ImGui::IsKeyPressed(GLFW_KEY_SPACE)) {
                m_playing = !m_playing;
                m_play_clock = glfwGetTime();
            }
            if (ImGui::IsKeyPressed(GLFW_KEY_LEFT)) set_frame(m_frame - 1);
            if (ImGui::IsKeyPressed(GLFW_KEY_RIGHT)) set_frame(m_frame + 1);
        }
    }
    if (glfwWindowShouldClose(m_window) && !m_quit) {
        glfwSetWindowShouldClose(m_window, 0);
        request_close();
    }
    poll_worker();
    poll_results();
    draw_menu();
    draw_viewer();
    draw_timeline();
    draw_side_panel();
    draw_modals();
    if (m_doc.is_open()) guarded([&] {
            if (m_doc.autosave_if_due(glfwGetTime())) m_info = "autosaved";
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
    GLFWwindow* window = glfwCreateWindow(opts.width, opts.height, "Refocus Studio", nullptr, nullptr);
    if (!window) {
        glfwTerminate();
        throw Error("cannot create an OpenGL 3.3 window");
    }
    glfwMakeContextCurrent(window);
    glfwSwapInterval(opts.script.empty() && opts.exit_after < 0 ? 1 : 0);

    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGui::GetIO().IniFilename = nullptr;
    ImGui::StyleColorsDark();
    ImGui_ImplGlfw_InitForOpenGL(window, true);
    ImGui_ImplOpenGL3_Init("#version 330 core");

    int code = 0;
    {
        Studio studio(window, opts);
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
            if (opts.exit_after >= 0 && rendered >= opts.exit_after) {
                if (!opts.screenshot.empty()) studio.screenshot(opts.screenshot);
                break;
            }
            glfwSwapBuffers(window);
        }
    }
    ImGui_ImplOpenGL3_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
    glfwDestroyWindow(window);
    glfwTerminate();
    return code;
}

}  // namespace refocus
