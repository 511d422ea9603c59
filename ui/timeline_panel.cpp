#include "timeline_panel.h"

#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>

#include "focus_panel.h"
#include "studio_context.h"

namespace refocus {

namespace {

// Play / pause, the frame steps and the playhead slider; moves the playhead while playing.
void draw_transport(TimelineState& s, StudioContext& ctx) {
    const int n = ctx.source->frames();
    if (ImGui::Button(s.playing ? "Pause" : "Play")) toggle_playback(s);
    ImGui::SameLine();
    if (ImGui::ArrowButton("prev", ImGuiDir_Left)) ctx.set_frame(ctx.frame - 1);
    ImGui::SameLine();
    if (ImGui::ArrowButton("next", ImGuiDir_Right)) ctx.set_frame(ctx.frame + 1);
    ImGui::SameLine();
    ImGui::SetNextItemWidth(-1);
    int f = ctx.frame;
    if (ImGui::SliderInt("##frame", &f, 0, n - 1, "frame %d")) ctx.set_frame(f);
    if (s.playing) {
        const double now = glfwGetTime();
        const int steps = static_cast<int>((now - s.play_clock) * ctx.source->fps());
        if (steps > 0) {
            ctx.set_frame((ctx.frame + steps) % n);
            s.play_clock += steps / ctx.source->fps();
        }
    }
}

}  // namespace

void toggle_playback(TimelineState& s) {
    s.playing = !s.playing;
    s.play_clock = glfwGetTime();
}

void draw_timeline(TimelineState& s, StudioContext& ctx) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    ImGui::SetNextWindowPos(
        ImVec2(vp->WorkPos.x, vp->WorkPos.y + vp->WorkSize.y - kTimelineHeight));
    ImGui::SetNextWindowSize(ImVec2(vp->WorkSize.x - kSidePanelWidth, kTimelineHeight));
    ImGui::Begin("Timeline", nullptr,
                 ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                     ImGuiWindowFlags_NoSavedSettings);
    if (!ctx.source) {
        ImGui::End();
        return;
    }
    draw_transport(s, ctx);
    const int n = ctx.source->frames();
    // Lanes: one row per focus parameter, keyframes as diamonds.
    ImDrawList* dl = ImGui::GetWindowDrawList();
    const float label_w = 110.0f, row_h = 18.0f;
    const ImVec2 origin = ImGui::GetCursorScreenPos();
    const float lane_w = ImGui::GetContentRegionAvail().x - label_w;
    auto frame_x = [&](double fr) { return origin.x + label_w + (fr + 0.5) / n * lane_w; };
    const auto& lanes = focus_lanes();
    for (size_t i = 0; i < lanes.size(); ++i) {
        const float y = origin.y + i * row_h;
        dl->AddText(ImVec2(origin.x, y + 2), IM_COL32(200, 200, 200, 255), lanes[i].name);
        dl->AddRectFilled(ImVec2(origin.x + label_w, y + 1),
                          ImVec2(origin.x + label_w + lane_w, y + row_h - 1),
                          IM_COL32(40, 40, 46, 255));
        for (const Keyframe& k : (ctx.doc.focus().*(lanes[i].lane)).keys) {
            const float cx = frame_x(k.frame), cy = y + row_h * 0.5f, r = 5.0f;
            dl->AddQuadFilled(ImVec2(cx, cy - r), ImVec2(cx + r, cy), ImVec2(cx, cy + r),
                              ImVec2(cx - r, cy), IM_COL32(240, 190, 60, 255));
        }
    }
    if (ctx.doc.focus().track) {
        const auto& tr = *ctx.doc.focus().track;
        const float y = origin.y + 0.5f * row_h;
        dl->AddLine(ImVec2(frame_x(tr.from_frame), y), ImVec2(frame_x(tr.to_frame), y),
                    IM_COL32(90, 200, 255, 200), 3.0f);
    }
    const float total_h = lanes.size() * row_h;
    dl->AddLine(ImVec2(frame_x(ctx.frame), origin.y),
                ImVec2(frame_x(ctx.frame), origin.y + total_h), IM_COL32(255, 80, 80, 255), 2.0f);
    ImGui::SetCursorScreenPos(ImVec2(origin.x + label_w, origin.y));
    ImGui::InvisibleButton("lanes", ImVec2(std::max(lane_w, 1.0f), total_h));
    if (ImGui::IsItemHovered()) {
        const ImVec2 mp = ImGui::GetMousePos();
        const int fr =
            std::clamp(static_cast<int>((mp.x - origin.x - label_w) / lane_w * n), 0, n - 1);
        const int row = static_cast<int>((mp.y - origin.y) / row_h);
        if (ImGui::IsMouseDown(0)) ctx.set_frame(fr);
        if (ImGui::IsMouseClicked(1) && row >= 0 && row < static_cast<int>(lanes.size())) {
            Lane& lane = ctx.doc.focus().*(lanes[row].lane);
            for (const Keyframe& k : lane.keys)
                if (std::abs(frame_x(k.frame) - mp.x) < 6.0f) {
                    lane.remove(k.frame);
                    ctx.changed();
                    break;
                }
        }
    }
    ImGui::End();
}

}  // namespace refocus
