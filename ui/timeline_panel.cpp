#include "timeline_panel.h"

#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "focus_panel.h"
#include "studio_context.h"

namespace refocus {

namespace {

bool button(const char* label, const char* tip) {
    const bool r = ImGui::Button(label);
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", tip);
    ImGui::SameLine();
    return r;
}

// Play / pause, the frame steps, in and out points, the timecode and the playhead slider.
void draw_transport(TimelineState& s, StudioContext& ctx) {
    const int n = ctx.source->frames();
    if (button("|<", "First frame, or the in point (Home)")) ctx.set_frame(ctx.first_frame());
    if (button("<", "Previous frame (Left)")) ctx.set_frame(ctx.frame - 1);
    if (button(s.playing ? "Pause" : "Play", "Play / pause (Space); J, K, L shuttle"))
        toggle_playback(s);
    if (button(">", "Next frame (Right)")) ctx.set_frame(ctx.frame + 1);
    if (button(">|", "Last frame, or the out point (End)")) ctx.set_frame(ctx.last_frame());
    if (button("In", "Set the in point at the playhead (I); playback and export keep to it"))
        set_in_point(ctx, ctx.frame);
    if (button("Out", "Set the out point at the playhead (O)")) set_out_point(ctx, ctx.frame);
    if (ctx.in_frame >= 0 || ctx.out_frame >= 0)
        if (button("Clear", "Clear the in and out points (Alt+X)"))
            ctx.in_frame = ctx.out_frame = -1;
    ImGui::Text("%s  frame %d / %d", timecode(ctx.frame, ctx.source->fps()).c_str(), ctx.frame,
                n - 1);
    if (s.playing && s.rate != 1) {
        ImGui::SameLine();
        ImGui::TextColored(ImVec4(1, 0.8f, 0.3f, 1), "%+dx", s.rate);
    }
    ImGui::SetNextItemWidth(-1);
    int f = ctx.frame;
    if (ImGui::SliderInt("##frame", &f, 0, n - 1, "frame %d")) ctx.set_frame(f);
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("The playhead: drag to scrub");
}

// Frame numbers and timecode every few frames, and the in/out range, above the lanes.
void draw_ruler(StudioContext& ctx, float label_w) {
    const int n = ctx.source->frames();
    ImDrawList* dl = ImGui::GetWindowDrawList();
    const ImVec2 o = ImGui::GetCursorScreenPos();
    const float w = ImGui::GetContentRegionAvail().x - label_w, h = 16.0f;
    auto x_of = [&](double fr) { return o.x + label_w + (fr + 0.5) / n * w; };
    dl->AddRectFilled(ImVec2(x_of(ctx.first_frame() - 0.5), o.y),
                      ImVec2(x_of(ctx.last_frame() + 0.5), o.y + h), IM_COL32(60, 80, 110, 255));
    // A label every `step` frames, at least 70 px apart.
    int step = 1;
    for (int c : {1, 2, 5, 10, 25, 50, 100, 250, 500, 1000, 2500, 5000})
        if ((step = c) * w / n >= 70.0f) break;
    for (int fr = 0; fr < n; fr += step) {
        dl->AddLine(ImVec2(x_of(fr), o.y + h - 5), ImVec2(x_of(fr), o.y + h),
                    IM_COL32(180, 180, 180, 255));
        dl->AddText(ImVec2(x_of(fr) + 2, o.y), IM_COL32(170, 170, 170, 255),
                    std::to_string(fr).c_str());
    }
    dl->AddText(ImVec2(o.x, o.y), IM_COL32(200, 200, 200, 255), "frame");
    ImGui::Dummy(ImVec2(label_w + w, h));
}

}  // namespace

void toggle_playback(TimelineState& s) {
    s.playing = !s.playing;
    s.rate = 1;
    s.play_clock = glfwGetTime();
}

void shuttle(TimelineState& s, int direction) {
    if (direction == 0) {
        s.playing = false;
        s.rate = 1;
        return;
    }
    if (s.playing && (s.rate > 0) == (direction > 0))
        s.rate = std::clamp(s.rate * 2, -8, 8);
    else
        s.rate = direction;
    if (!s.playing) s.play_clock = glfwGetTime();
    s.playing = true;
}

void advance_playback(TimelineState& s, StudioContext& ctx) {
    if (!s.playing || !ctx.source) return;
    const double now = glfwGetTime(), fps = ctx.source->fps() * std::abs(s.rate);
    const int steps = static_cast<int>((now - s.play_clock) * fps);
    if (steps <= 0) return;
    s.play_clock += steps / fps;
    const int a = ctx.first_frame(), b = std::max(ctx.last_frame(), a), len = b - a + 1;
    const int off = ctx.frame - a + (s.rate > 0 ? steps : -steps);
    ctx.set_frame(a + ((off % len) + len) % len);
    ctx.playback.played += steps;
}

void set_in_point(StudioContext& ctx, int frame) {
    ctx.in_frame = frame;
    if (ctx.out_frame >= 0 && ctx.out_frame < frame) ctx.out_frame = -1;
}

void set_out_point(StudioContext& ctx, int frame) {
    ctx.out_frame = frame;
    if (ctx.in_frame > frame) ctx.in_frame = -1;
}

std::string timecode(int frame, double fps) {
    const int ifps = std::max(1, static_cast<int>(std::lround(fps)));
    const int ff = frame % ifps, secs = frame / ifps;
    char b[32];
    std::snprintf(b, sizeof b, "%02d:%02d:%02d:%02d", secs / 3600, secs / 60 % 60, secs % 60, ff);
    return b;
}

void draw_timeline(TimelineState& s, StudioContext& ctx) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const Layout::Rect r =
        ctx.layout.timeline(vp->WorkPos.x, vp->WorkPos.y, vp->WorkSize.x, vp->WorkSize.y);
    ImGui::SetNextWindowPos(ImVec2(r.x, r.y));
    ImGui::SetNextWindowSize(ImVec2(r.w, r.h));
    ImGui::Begin("Timeline", nullptr,
                 ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                     ImGuiWindowFlags_NoSavedSettings);
    if (!ctx.source) {
        ImGui::End();
        return;
    }
    draw_transport(s, ctx);
    draw_ruler(ctx, 110.0f);
    draw_key_lanes(s.keys, ctx, ImGui::GetCursorScreenPos(), ImGui::GetContentRegionAvail());
    ImGui::End();
}

}  // namespace refocus
