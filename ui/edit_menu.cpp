#include "edit_menu.h"

#include <GLFW/glfw3.h>
#include <imgui.h>

#include <string>

#include "studio_context.h"

namespace refocus {

bool undo_document(StudioContext& ctx) {
    if (!ctx.doc.is_open()) return false;
    const std::string label = ctx.doc.undo_label();
    if (!ctx.doc.undo()) return false;
    ctx.changed();
    ctx.info = "undid: " + (label.empty() ? std::string("edit focus") : label);
    return true;
}

bool redo_document(StudioContext& ctx) {
    if (!ctx.doc.is_open()) return false;
    const std::string label = ctx.doc.redo_label();
    if (!ctx.doc.redo()) return false;
    ctx.changed();
    ctx.info = "redid: " + label;
    return true;
}

void draw_edit_menu(StudioContext& ctx) {
    if (!ImGui::BeginMenu("Edit")) return;
    const bool open = ctx.doc.is_open();
    const std::string undo = open && ctx.doc.can_undo() ? "Undo " + ctx.doc.undo_label() : "Undo";
    const std::string redo = open && ctx.doc.can_redo() ? "Redo " + ctx.doc.redo_label() : "Redo";
    if (ImGui::MenuItem(undo.c_str(), "Ctrl+Z", false, open && ctx.doc.can_undo()))
        undo_document(ctx);
    if (ImGui::MenuItem(redo.c_str(), "Ctrl+Shift+Z", false, open && ctx.doc.can_redo()))
        redo_document(ctx);
    ImGui::Separator();
    ImGui::TextDisabled("Focus keys and tracking; atlas strokes undo in the atlas editor.");
    ImGui::EndMenu();
}

void handle_edit_keys(StudioContext& ctx, bool atlas_shown) {
    if (!ctx.doc.is_open()) return;
    // A drag or a typed value is still going on while an item is active or the mouse is down.
    if (!ImGui::IsAnyItemActive() && !ImGui::IsMouseDown(0)) ctx.doc.commit("Edit focus");
    const ImGuiIO& io = ImGui::GetIO();
    if (atlas_shown || io.WantTextInput || !io.KeyCtrl) return;
    if (ImGui::IsKeyPressed(GLFW_KEY_Z)) io.KeyShift ? redo_document(ctx) : undo_document(ctx);
    if (ImGui::IsKeyPressed(GLFW_KEY_Y)) redo_document(ctx);
}

}  // namespace refocus
