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
    draw_key_lanes(s.keys, ctx, ImGui::GetCursorScreenPos(), ImGui::GetContentRegionAvail());
    ImGui::End();
}

}  // namespace refocus
