#include "layout.h"

#include <imgui.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>

namespace refocus {

namespace fs = std::filesystem;

Layout::Rect Layout::viewer(float vx, float vy, float vw, float vh) const {
    return {vx, vy, vw - side_w, vh - timeline_h - kStatusH};
}
Layout::Rect Layout::timeline(float vx, float vy, float vw, float vh) const {
    return {vx, vy + vh - timeline_h - kStatusH, vw - side_w, timeline_h};
}
Layout::Rect Layout::side(float vx, float vy, float vw, float vh) const {
    return {vx + vw - side_w, vy, side_w, vh - kStatusH};
}
Layout::Rect Layout::status(float vx, float vy, float vw, float vh) const {
    return {vx, vy + vh - kStatusH, vw, kStatusH};
}

// Each panel keeps room for its controls; the viewer keeps at least a quarter of the window.
void Layout::clamp_to(float vw, float vh) {
    side_w = std::clamp(side_w, 260.0f, std::max(260.0f, vw * 0.6f));
    timeline_h = std::clamp(timeline_h, 120.0f, std::max(120.0f, vh * 0.6f));
}

std::string layout_file() {
    const char* xdg = std::getenv("XDG_CONFIG_HOME");
    const char* home = std::getenv("HOME");
    if (xdg && *xdg) return (fs::path(xdg) / "refocus" / "studio_layout.json").string();
    if (home && *home)
        return (fs::path(home) / ".config" / "refocus" / "studio_layout.json").string();
    return "";
}

Layout load_layout() {
    Layout l;
    const std::string f = layout_file();
    if (f.empty()) return l;
    try {
        std::ifstream in(f);
        if (!in) return l;
        const nlohmann::json j = nlohmann::json::parse(in);
        l.side_w = j.value("side_width", l.side_w);
        l.timeline_h = j.value("timeline_height", l.timeline_h);
        l.window_w = std::clamp(j.value("window_width", l.window_w), 640, 16384);
        l.window_h = std::clamp(j.value("window_height", l.window_h), 400, 16384);
    } catch (...) {
        return Layout{};
    }
    return l;
}

void save_layout(const Layout& l) {
    const std::string f = layout_file();
    if (f.empty()) return;
    std::error_code ec;
    fs::create_directories(fs::path(f).parent_path(), ec);
    const nlohmann::json j = {{"side_width", l.side_w},
                              {"timeline_height", l.timeline_h},
                              {"window_width", l.window_w},
                              {"window_height", l.window_h}};
    const std::string tmp = f + ".tmp";
    {
        std::ofstream out(tmp);
        if (!(out << j.dump(2))) return;
    }
    fs::rename(tmp, f, ec);
}

bool drag_splitters(Layout& l) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const ImVec2 p = vp->WorkPos, s = vp->WorkSize;
    const Layout::Rect side = l.side(p.x, p.y, s.x, s.y), tl = l.timeline(p.x, p.y, s.x, s.y);
    // Two thin invisible windows over the seams, so ImGui routes the mouse to them first.
    auto splitter = [](const char* id, ImVec2 pos, ImVec2 size, ImGuiMouseCursor cursor,
                       float& value, float delta_sign, bool vertical) {
        ImGui::SetNextWindowPos(pos);
        ImGui::SetNextWindowSize(size);
        ImGui::PushStyleVar(ImGuiStyleVar_WindowPadding, ImVec2(0, 0));
        ImGui::PushStyleVar(ImGuiStyleVar_WindowMinSize, ImVec2(1, 1));
        ImGui::Begin(id, nullptr,
                     ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoBackground |
                         ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing);
        ImGui::InvisibleButton("seam", size);
        const bool active = ImGui::IsItemActive();
        if (ImGui::IsItemHovered() || active) ImGui::SetMouseCursor(cursor);
        if (ImGui::IsItemHovered() && !active)
            ImGui::SetTooltip("Drag to resize the panels (remembered)");
        if (active) {
            const ImVec2 d = ImGui::GetIO().MouseDelta;
            value += delta_sign * (vertical ? d.x : d.y);
        }
        ImGui::End();
        ImGui::PopStyleVar(2);
        return active;
    };
    bool dragging = splitter("##split_side", ImVec2(side.x - 3, side.y), ImVec2(6, side.h),
                             ImGuiMouseCursor_ResizeEW, l.side_w, -1.0f, true);
    dragging |= splitter("##split_timeline", ImVec2(tl.x, tl.y - 3), ImVec2(tl.w, 6),
                         ImGuiMouseCursor_ResizeNS, l.timeline_h, -1.0f, false);
    l.clamp_to(s.x, s.y);
    return dragging;
}

}  // namespace refocus
