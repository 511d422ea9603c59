#include "focus_panel.h"

#include <imgui.h>

#include <algorithm>
#include <cmath>

#include "studio_context.h"
#include "util/error.h"
#include "viewer_panel.h"

namespace refocus {

const std::vector<LaneInfo>& focus_lanes() {
    static const std::vector<LaneInfo> lanes = {
        {"focus", &FocusTrack::focus, -2.0, 20.0, "%.2f"},
        {"aperture", &FocusTrack::aperture, 0.0, 4.0, "%.2f"},
        {"blades", &FocusTrack::blades, 0.0, 12.0, "%.0f"},
        {"rotation", &FocusTrack::rotation_deg, 0.0, 180.0, "%.0f deg"},
        {"rim (beta)", &FocusTrack::beta, 0.4, 10.0, "%.2f"},
        {"highlights", &FocusTrack::highlight_gain, 0.0, 8.0, "%.2f"},
    };
    return lanes;
}

void set_focus_key(StudioContext& ctx, const std::string& name, int frame, double value, Easing e) {
    for (const LaneInfo& l : focus_lanes())
        if (name == l.name || (name == "rim" && l.lane == &FocusTrack::beta) ||
            (name == "beta" && l.lane == &FocusTrack::beta) ||
            (name == "highlight_gain" && l.lane == &FocusTrack::highlight_gain) ||
            (name == "rotation_deg" && l.lane == &FocusTrack::rotation_deg)) {
            if (!std::isfinite(value))
                throw Error("keyframe value for " + name + " is not a number");
            (ctx.doc.focus().*(l.lane)).set(frame, std::clamp(value, l.min, l.max), e);
            ctx.changed();
            return;
        }
    throw Error("unknown focus lane '" + name + "'");
}

void focus_at_pixel(StudioContext& ctx, Easing e, int frame, int x, int y) {
    if (!ctx.depth) throw Error("the depth is not ready yet: fit the project first (Fit tab)");
    if (!ctx.view || ctx.view->t != frame)
        throw Error("frame " + std::to_string(frame) + " is still rendering");
    const FrameMaps& m = ctx.view->maps;
    const float d = ctx.depth->depth_at_pixel(frame, x, y, m.uv_bg, m.uv_fg, m.alpha);
    set_focus_key(ctx, "focus", frame, d, e);
    // Refocusing needs an aperture: the clip's own (1) when none is keyed yet.
    if (ctx.doc.focus().aperture.keys.empty()) set_focus_key(ctx, "aperture", frame, 1.0, e);
    ctx.info = "focus key at frame " + std::to_string(frame);
}

void track_pixel(StudioContext& ctx, Easing e, int frame, int x, int y) {
    if (!ctx.depth) throw Error("the depth is not ready yet: fit the project first (Fit tab)");
    if (!ctx.view || ctx.view->t != frame)
        throw Error("frame " + std::to_string(frame) + " is still rendering");
    const FrameMaps& m = ctx.view->maps;
    FocusTarget tgt;
    const bool fg = !m.alpha.empty() && m.alpha.at(x, y, 0) > 0.5f;
    const Image& uv = fg ? m.uv_fg : m.uv_bg;
    tgt.layer = fg ? DepthModel::Foreground : DepthModel::Background;
    tgt.u = uv.at(x, y, 0);
    tgt.v = uv.at(x, y, 1);
    tgt.from_frame = 0;
    tgt.to_frame = ctx.source->frames() - 1;
    ctx.doc.focus().track = tgt;
    if (ctx.doc.focus().aperture.keys.empty()) set_focus_key(ctx, "aperture", frame, 1.0, e);
    ctx.changed();
    ctx.info = std::string("tracking a point of the ") + (fg ? "foreground" : "background");
}

namespace {

// One slider per lane at the playhead, each with its key / del button.
void draw_lane_sliders(FocusPanelState& s, StudioContext& ctx) {
    FocusTrack& ft = ctx.doc.focus();
    const PreviewLens lens = ft.lens_at(ctx.frame, ctx.depth.get());
    const double current[] = {lens.focus,        lens.aperture, double(lens.blades),
                              lens.rotation_deg, lens.beta,     lens.highlight_gain};
    const auto& lanes = focus_lanes();
    for (size_t i = 0; i < lanes.size(); ++i) {
        float v = static_cast<float>(current[i]);
        ImGui::PushID(static_cast<int>(i));
        ImGui::SetNextItemWidth(200);
        if (ImGui::SliderFloat(lanes[i].name, &v, static_cast<float>(lanes[i].min),
                               static_cast<float>(lanes[i].max), lanes[i].format))
            ctx.guarded([&] { set_focus_key(ctx, lanes[i].name, ctx.frame, v, s.new_key_easing); });
        ImGui::SameLine();
        Lane& lane = ft.*(lanes[i].lane);
        const bool keyed = std::any_of(lane.keys.begin(), lane.keys.end(),
                                       [&](const Keyframe& k) { return k.frame == ctx.frame; });
        if (ImGui::SmallButton(keyed ? "del" : "key")) {
            if (keyed)
                lane.remove(ctx.frame);
            else
                lane.set(ctx.frame, current[i], s.new_key_easing);
            ctx.changed();
        }
        ImGui::PopID();
    }
}

// Arms a click on the viewer; the input view shows no depth, so the viewer turns to the lens.
void arm_pick(ViewerState& viewer, StudioContext& ctx, ViewerState::Pick pick) {
    viewer.pick = viewer.pick == pick ? ViewerState::Pick::None : pick;
    if (!viewer.mode->needs_fit) set_view_mode(viewer, ctx, view_mode("refocused"));
}

void draw_tracking(StudioContext& ctx) {
    FocusTrack& ft = ctx.doc.focus();
    ImGui::Text("tracking %s point (%.3f, %.3f)", ft.track->layer ? "foreground" : "background",
                ft.track->u, ft.track->v);
    ImGui::SetNextItemWidth(200);
    int range[2] = {ft.track->from_frame, ft.track->to_frame};
    if (ImGui::DragInt2("frames", range, 0.2f, 0, ctx.source ? ctx.source->frames() - 1 : 0)) {
        ft.track->from_frame = std::min(range[0], range[1]);
        ft.track->to_frame = std::max(range[0], range[1]);
        ctx.changed();
    }
    if (ImGui::Button("Stop tracking")) {
        ft.track.reset();
        ctx.changed();
    }
}

}  // namespace

void draw_focus_panel(FocusPanelState& s, ViewerState& viewer, StudioContext& ctx) {
    if (!ctx.doc.is_open()) {
        ImGui::TextWrapped("Open a project first.");
        return;
    }
    if (!ctx.depth)
        ImGui::TextWrapped(
            "Depth appears after a fit (it is fitted to the radius maps); until then "
            "the refocused view shows the sharp composite.");
    else
        ImGui::Text("depth fitted: rms %.2f px", ctx.depth->rms_px);
    ImGui::TextWrapped("Values at frame %d. Changing one sets a keyframe there.", ctx.frame);
    const char* easings[] = {"linear", "ease in-out", "hold"};
    int e = static_cast<int>(s.new_key_easing);
    if (ImGui::Combo("new keys", &e, easings, 3)) s.new_key_easing = static_cast<Easing>(e);
    draw_lane_sliders(s, ctx);
    ImGui::Separator();
    using Pick = ViewerState::Pick;
    if (ImGui::Button(viewer.pick == Pick::Focus ? "click the viewer..." : "Click to focus"))
        arm_pick(viewer, ctx, Pick::Focus);
    ImGui::SameLine();
    if (ImGui::Button(viewer.pick == Pick::Track ? "click the viewer..." : "Track a point"))
        arm_pick(viewer, ctx, Pick::Track);
    if (ctx.doc.focus().track) draw_tracking(ctx);
    ImGui::TextWrapped(
        "Rack focus: key the focus at two frames (e.g. click the background at the "
        "first frame and the subject at a later one); ease in-out eases between them.");
}

}  // namespace refocus
