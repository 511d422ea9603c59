// The menu bar (File, View, the fit's state) and the modal prompts: open, new, save as, unsaved
// changes, restoring an autosave, errors.
#include <GLFW/glfw3.h>
#include <imgui.h>

#include "edit_menu.h"
#include "studio_app.h"
#include "util/error.h"

namespace refocus {

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
        if (ImGui::MenuItem("Open...", "Ctrl+O", false, idle)) d.show_open = true;
        if (ImGui::BeginMenu("Open recent", idle)) {
            auto list = recent_projects();
            if (list.empty()) ImGui::MenuItem("(none)", nullptr, false, false);
            for (const auto& r : list)
                if (ImGui::MenuItem(r.c_str())) {
                    if (m_ctx.doc.dirty()) {
                        d.pending_path = r;
                        ask_unsaved(DialogState::Pending::Open);
                    } else {
                        m_ctx.guarded([&] { open_project(r); });
                    }
                }
            ImGui::EndMenu();
        }
        if (ImGui::MenuItem("Save", "Ctrl+S", false, m_ctx.doc.is_open()))
            m_ctx.guarded([&] { save(); });
        if (ImGui::MenuItem("Save as...", "Ctrl+Shift+S", false, m_ctx.doc.is_open() && idle))
            d.show_save_as = true;
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
    if (path_popup("Open project", "Project folder, or a clip (video, image folder or pattern):",
                   d.path_buf, sizeof d.path_buf, "Open")) {
        if (m_ctx.doc.dirty()) {
            d.pending_path = d.path_buf;
            ask_unsaved(DialogState::Pending::Open);
        } else {
            m_ctx.guarded([&] { open_project(d.path_buf); });
        }
    }
    if (ImGui::BeginPopupModal("New project", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::TextUnformatted("Clip (video file, image folder or printf pattern):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##clip", d.clip_buf, sizeof d.clip_buf);
        ImGui::TextUnformatted("New project folder (created):");
        ImGui::SetNextItemWidth(520);
        ImGui::InputText("##dir", d.path_buf, sizeof d.path_buf);
        if (ImGui::Button("Create")) {
            ImGui::CloseCurrentPopup();
            if (m_ctx.doc.dirty()) {
                d.pending_clip = d.clip_buf;
                d.pending_path = d.path_buf;
                ask_unsaved(DialogState::Pending::New);
            } else {
                m_ctx.guarded([&] { new_project(d.clip_buf, d.path_buf); });
            }
        }
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    if (path_popup("Save project as",
                   "New project folder (the project, its fit and edits are copied):", d.path_buf,
                   sizeof d.path_buf, "Save"))
        m_ctx.guarded([&] { save_as(d.path_buf); });
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
            "This project has autosaved changes newer than its last save\n"
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
    draw_path_dialogs();
    draw_unsaved_dialog();
    draw_autosave_and_error();
}

}  // namespace refocus
