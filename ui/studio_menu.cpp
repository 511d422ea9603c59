// The menu bar (File, View, the fit's state) and the modal prompts: open, new, save as, unsaved
// changes, restoring an autosave, errors; the file browser the prompts and the start screen
// open, and paths dropped on the window.
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <cstdio>
#include <string>

#include "edit_menu.h"
#include "studio_app.h"
#include "util/error.h"

namespace refocus {

namespace {
// A typed path with "Browse..." beside it; true when `ok` (or Enter) was pressed. `browse` is
// set when the browser is asked for: the prompt closes, and the browser comes back to it.
bool path_popup(const char* title, const char* prompt, char* buf, size_t n, const char* ok,
                const char* ok_tip, bool& browse) {
    bool go = false;
    if (ImGui::BeginPopupModal(title, nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted(prompt);
        ImGui::SetNextItemWidth(520);
        if (ImGui::IsWindowAppearing()) ImGui::SetKeyboardFocusHere();
        go = ImGui::InputText("##path", buf, n, ImGuiInputTextFlags_EnterReturnsTrue);
        item_tooltip("Type a path and press Enter, or browse for it");
        ImGui::SameLine();
        browse = ImGui::Button("Browse...");
        item_tooltip("Pick it in the file browser");
        go |= ImGui::Button(ok);
        item_tooltip(ok_tip);
        ImGui::SameLine();
        const bool cancel = ImGui::Button("Cancel");
        item_tooltip("Close without doing anything");
        if (cancel || go || browse) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    return go;
}

// The folder part of a typed path, for the browser to open on; empty when none was typed.
std::string folder_of(const char* typed) {
    if (!typed[0]) return "";
    const fs::path p = fs::absolute(typed);
    return fs::is_directory(p) ? p.string() : p.parent_path().string();
}
}  // namespace

void Studio::ask_open(const std::string& path) {
    if (m_ctx.doc.dirty()) {
        m_dialogs.pending_path = path;
        ask_unsaved(DialogState::Pending::Open);
    } else {
        m_ctx.guarded([&] { open_project(path); });
    }
}

void Studio::ask_unsaved(DialogState::Pending what) {
    m_dialogs.pending = what;
    m_dialogs.show_unsaved = true;
}

void Studio::draw_menu() {
    if (!ImGui::BeginMainMenuBar()) return;
    DialogState& d = m_dialogs;
    if (ImGui::BeginMenu("File")) {
        const bool idle = !m_ctx.busy_with_files();
        if (ImGui::MenuItem("New from clip...", "Ctrl+N", false, idle)) d.show_new = true;
        item_tooltip("Make a project from a video or an image sequence (type or browse)");
        if (ImGui::MenuItem("Open...", "Ctrl+O", false, idle)) d.show_open = true;
        item_tooltip(
            "Open a project folder, or a clip (a project is made beside it);\n"
            "dropping either onto the window does the same");
        if (ImGui::BeginMenu("Open recent", idle)) {
            auto list = recent_projects();
            if (list.empty()) ImGui::MenuItem("(none)", nullptr, false, false);
            for (const auto& r : list)
                if (ImGui::MenuItem(r.c_str())) ask_open(r);
            ImGui::EndMenu();
        }
        if (ImGui::MenuItem("Save", "Ctrl+S", false, m_ctx.doc.is_open()))
            m_ctx.guarded([&] { save(); });
        if (ImGui::MenuItem("Save as...", "Ctrl+Shift+S", false, m_ctx.doc.is_open() && idle))
            d.show_save_as = true;
        item_tooltip("Copy the project (frames, fit, edits) to a new folder and go on there");
        ImGui::Separator();
        if (ImGui::MenuItem("Quit", "Ctrl+Q")) request_close();
        ImGui::EndMenu();
    }
    draw_edit_menu(m_ctx);
    if (ImGui::BeginMenu("View")) {
        for (const ViewModeInfo& m : view_modes()) {
            const std::string key =
                m.key > 32 && m.key < 127 ? std::string(1, static_cast<char>(m.key)) : "";
            if (ImGui::MenuItem(m.name, key.empty() ? nullptr : key.c_str(),
                                m_viewer.mode == &m && !m_viewer.show_atlas))
                set_mode(m);
        }
        ImGui::Separator();
        ImGui::MenuItem("Atlas editor", "Tab", &m_viewer.show_atlas);
        if (ImGui::MenuItem("Time slice", nullptr, &m_viewer.slice.on)) m_viewer.slice.dirty = true;
        if (ImGui::BeginMenu("Preview renderer")) {
            // Auto: the GLSL passes, the CPU twin when no GL context could be had.
            using B = ViewRenderer::Backend;
            const B now = m_ctx.renderer->backend();
            for (auto [b, label] : {std::pair{B::Auto, "Auto"}, std::pair{B::Gpu, "GPU (GLSL)"},
                                    std::pair{B::Cpu, "CPU"}})
                if (ImGui::MenuItem(label, nullptr, now == b)) m_ctx.renderer->set_backend(b);
            ImGui::EndMenu();
        }
        if (ImGui::BeginMenu("Preview quality")) {
            const PreviewQuality now = m_ctx.renderer->quality();
            if (ImGui::MenuItem("Fast", nullptr, now == PreviewQuality::Fast))
                m_ctx.renderer->set_quality(PreviewQuality::Fast);
            item_tooltip(
                "The real-time depth of field: half-resolution disk gather, highlights as\n"
                "sprites; fast enough to play and scrub on software GL");
            if (ImGui::MenuItem("Exact", nullptr, now == PreviewQuality::Exact))
                m_ctx.renderer->set_quality(PreviewQuality::Exact);
            item_tooltip(
                "The reference gather, every source within reach: what exports render;\n"
                "seconds a frame on software GL");
            ImGui::EndMenu();
        }
        if (ImGui::BeginMenu("Proxy")) {
            // The viewer's picture size; exports always render at full size.
            const int now = m_ctx.renderer->proxy();
            for (auto [p, label] : {std::pair{0, "Auto (at most 1280 px wide)"},
                                    std::pair{1, "Full"}, std::pair{2, "1/2"}, std::pair{4, "1/4"}})
                if (ImGui::MenuItem(label, nullptr, now == p)) m_ctx.renderer->set_proxy(p);
            ImGui::EndMenu();
        }
        ImGui::EndMenu();
    }
    const auto st = m_ctx.worker->status();
    ImGui::SameLine(ImGui::GetWindowWidth() - 420);
    ImGui::TextDisabled("%s%s  |  fit: %s%s",
                        m_ctx.doc.is_open() ? m_ctx.doc.project().name.c_str() : "",
                        m_ctx.doc.dirty() ? " *" : "", state_name(st.state),
                        st.busy ? ("  |  " + st.busy_what).c_str() : "");
    ImGui::EndMainMenuBar();
}

void Studio::draw_path_dialogs() {
    DialogState& d = m_dialogs;
    bool want_browse = false;
    if (path_popup("Open project", "Project folder, or a clip (video, image folder or pattern):",
                   d.path_buf, sizeof d.path_buf, "Open",
                   "Open the project; a clip gets a project made beside it", want_browse))
        ask_open(d.path_buf);
    if (want_browse) browse(DialogState::Browse::Open, true, folder_of(d.path_buf));
    if (ImGui::BeginPopupModal("New project", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted("Clip (video file, image folder or printf pattern):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##clip", d.clip_buf, sizeof d.clip_buf);
        item_tooltip(
            "A video (mp4, mov, mkv, ...), a folder of frames, or a pattern such as\n"
            "shot/frame_%04d.exr");
        ImGui::SameLine();
        const bool browse_clip = ImGui::Button("Browse...##clip");
        item_tooltip("Pick the clip in the file browser (a frame stands for its folder)");
        ImGui::TextUnformatted("New project folder (created):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##dir", d.path_buf, sizeof d.path_buf);
        item_tooltip("The folder the project is made in: new, or empty");
        ImGui::SameLine();
        const bool browse_dir = ImGui::Button("Browse...##dir");
        item_tooltip("Pick a folder, or name a new one, in the file browser");
        const bool create = ImGui::Button("Create");
        item_tooltip("Decode the clip's frames into the new project, then open it");
        ImGui::SameLine();
        const bool cancel = ImGui::Button("Cancel");
        item_tooltip("Close without doing anything");
        if (create || cancel || browse_clip || browse_dir) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
        if (create) {
            if (m_ctx.doc.dirty()) {
                d.pending_clip = d.clip_buf;
                d.pending_path = d.path_buf;
                ask_unsaved(DialogState::Pending::New);
            } else {
                m_ctx.guarded([&] { new_project(d.clip_buf, d.path_buf); });
            }
        }
        if (browse_clip) browse(DialogState::Browse::NewClip, true, folder_of(d.clip_buf));
        if (browse_dir) browse(DialogState::Browse::NewFolder, true);
    }
    want_browse = false;
    if (path_popup("Save project as",
                   "New project folder (the project, its fit and edits are copied):", d.path_buf,
                   sizeof d.path_buf, "Save", "Copy the project there and go on in the copy",
                   want_browse))
        m_ctx.guarded([&] { save_as(d.path_buf); });
    if (want_browse) browse(DialogState::Browse::SaveAs, true);
}

// Opens the studio's browser for a prompt (or the start screen), on `dir` when given.
void Studio::browse(DialogState::Browse what, bool from_prompt, const std::string& dir) {
    using B = DialogState::Browse;
    DialogState& d = m_dialogs;
    d.browsing = what;
    d.back_to_prompt = from_prompt;
    BrowseOptions o;
    o.dir = dir;
    if (what == B::Open) {
        o.title = "Open a project or a clip";
    } else if (what == B::NewClip) {
        o.filter = BrowseFilter::Clips;
        o.title = "Clip for the new project";
        o.ok = "Choose";
    } else {
        // A folder: the one typed in the prompt, else beside the clip (new) or the project
        // (save as).
        o.mode = BrowseMode::Folder;
        o.ok = what == B::SaveAs ? "Save" : "Choose";
        o.title = what == B::SaveAs ? "Save the project as" : "Folder for the new project";
        fs::path p = from_prompt && d.path_buf[0] ? fs::absolute(d.path_buf) : fs::path();
        if (p.empty() && what == B::NewFolder && d.clip_buf[0]) {
            const fs::path clip = fs::absolute(d.clip_buf);
            p = clip.parent_path() / (clip.stem().string() + "_refocus");
        }
        if (p.empty() && what == B::SaveAs && m_ctx.doc.is_open())
            p = m_ctx.doc.project().dir.parent_path() / (m_ctx.doc.project().name + "_copy");
        if (!p.empty() && o.dir.empty()) o.dir = p.parent_path().string();
        if (!p.empty() && !fs::is_directory(p)) o.name = p.filename().string();
    }
    d.browser.open(o);
}

// What the browser picked goes where it was asked for: the prompt's field, or straight on
// (open, save as). Cancel goes back to the prompt it came from.
void Studio::draw_browser() {
    using B = DialogState::Browse;
    DialogState& d = m_dialogs;
    const BrowseEvent ev = d.browser.draw();
    if (ev == BrowseEvent::None) return;
    const B what = d.browsing;
    d.browsing = B::None;
    if (ev == BrowseEvent::Cancelled) {
        if (!d.back_to_prompt) return;
        d.show_open = what == B::Open;
        d.show_new = what == B::NewClip || what == B::NewFolder;
        d.show_save_as = what == B::SaveAs;
        return;
    }
    const std::string& p = d.browser.picked();
    if (what == B::Open) ask_open(p);
    if (what == B::SaveAs) m_ctx.guarded([&] { save_as(p); });
    if (what == B::NewClip) {
        std::snprintf(d.clip_buf, sizeof d.clip_buf, "%s", p.c_str());
        // The same folder File > Open would make for the clip, unless one was given.
        const fs::path clip(p);
        if (!d.path_buf[0])
            std::snprintf(d.path_buf, sizeof d.path_buf, "%s",
                          (clip.parent_path() / (clip.stem().string() + "_refocus")).c_str());
        d.show_new = true;
    }
    if (what == B::NewFolder) {
        std::snprintf(d.path_buf, sizeof d.path_buf, "%s", p.c_str());
        d.show_new = true;
    }
}

// Paths dropped on the window and the start screen's buttons, as the File menu does them.
void Studio::take_requests() {
    DialogState& d = m_dialogs;
    if (!d.dropped.empty()) {
        const std::string first = d.dropped.front();
        if (d.dropped.size() > 1)
            m_ctx.info = "dropped " + std::to_string(d.dropped.size()) + " paths: opened " + first;
        d.dropped.clear();
        ask_open(first);
    }
    const StartRequest r = take_start_request();
    if (r.kind == StartRequest::Open) browse(DialogState::Browse::Open, false);
    if (r.kind == StartRequest::NewFromClip) {
        d.clip_buf[0] = d.path_buf[0] = 0;
        browse(DialogState::Browse::NewClip, false);
    }
    if (r.kind == StartRequest::OpenPath) ask_open(r.path);
    // The browsers' places: the open project's folder and the recent projects that still exist.
    const std::string project = m_ctx.doc.is_open() ? m_ctx.doc.project().dir.string() : "";
    if (project != d.places_for) {
        d.places_for = project;
        BrowserPlaces& pl = browser_places();
        pl.project = project;
        pl.recent.clear();
        std::error_code ec;
        for (const std::string& r : recent_projects())
            if (fs::is_directory(r, ec)) pl.recent.push_back(r);
    }
}

// Save, discard or cancel, then go on with what was asked (quit, open, new).
void Studio::draw_unsaved_dialog() {
    if (!ImGui::BeginPopupModal("Unsaved changes", nullptr, ImGuiWindowFlags_AlwaysAutoResize))
        return;
    DialogState& d = m_dialogs;
    ImGui::Text("%s has unsaved changes (focus keyframes, atlas paint).",
                m_ctx.doc.is_open() ? m_ctx.doc.project().name.c_str() : "The project");
    auto proceed = [&] {
        const DialogState::Pending p = d.pending;
        d.pending = DialogState::Pending::None;
        if (p == DialogState::Pending::Quit) m_quit = true;
        if (p == DialogState::Pending::Open) m_ctx.guarded([&] { open_project(d.pending_path); });
        if (p == DialogState::Pending::New)
            m_ctx.guarded([&] { new_project(d.pending_clip, d.pending_path); });
    };
    if (ImGui::Button("Save")) {
        ImGui::CloseCurrentPopup();
        bool ok = true;
        try {
            save();
        } catch (const std::exception& e) {
            ok = false;  // the error shows; nothing is closed
            m_ctx.error = e.what();
        }
        if (ok) proceed();
    }
    ImGui::SameLine();
    if (ImGui::Button("Discard")) {
        ImGui::CloseCurrentPopup();
        m_ctx.doc.discard_autosave();
        proceed();
    }
    ImGui::SameLine();
    if (ImGui::Button("Cancel")) {
        d.pending = DialogState::Pending::None;
        ImGui::CloseCurrentPopup();
    }
    ImGui::EndPopup();
}

void Studio::draw_autosave_and_error() {
    if (m_ctx.doc.is_open() && m_ctx.doc.has_newer_autosave()) ImGui::OpenPopup("Restore autosave");
    if (ImGui::BeginPopupModal("Restore autosave", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted(
            "This project has autosaved changes that differ from its last save\n"
            "(the studio was closed without saving). Restore them?");
        if (ImGui::Button("Restore")) {
            m_ctx.guarded([&] { m_ctx.doc.restore_autosave(); });
            m_ctx.view_dirty = true;
            ImGui::CloseCurrentPopup();
        }
        ImGui::SameLine();
        if (ImGui::Button("Discard")) {
            m_ctx.doc.discard_autosave();
            ImGui::CloseCurrentPopup();
        }
        ImGui::EndPopup();
    }
    if (!m_ctx.error.empty()) ImGui::OpenPopup("Error");
    if (ImGui::BeginPopupModal("Error", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::PushTextWrapPos(600);
        ImGui::TextUnformatted(m_ctx.error.c_str());
        ImGui::PopTextWrapPos();
        if (ImGui::Button("OK")) {
            m_ctx.error.clear();
            ImGui::CloseCurrentPopup();
        }
        ImGui::EndPopup();
    }
}

void Studio::draw_modals() {
    auto open_popup = [](bool& flag, const char* name) {
        if (flag) ImGui::OpenPopup(name);
        flag = false;
    };
    open_popup(m_dialogs.show_open, "Open project");
    open_popup(m_dialogs.show_new, "New project");
    open_popup(m_dialogs.show_save_as, "Save project as");
    open_popup(m_dialogs.show_unsaved, "Unsaved changes");
    take_requests();
    draw_path_dialogs();
    draw_browser();
    draw_unsaved_dialog();
    draw_autosave_and_error();
}

}  // namespace refocus
