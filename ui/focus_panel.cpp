#include "focus_panel.h"

#include <imgui.h>

#include <algorithm>
#include <cmath>

#include "item_tip.h"
#include "studio_context.h"
#include "util/error.h"
#include "viewer_panel.h"

namespace refocus {

const std::vector<LaneInfo>& focus_lanes() {
    static const std::vector<LaneInfo> lanes = {
        {"focus", &FocusTrack::focus, -2.0, 20.0, "%.2f",
         "The depth in focus (inverse depth, the depth model's units: larger is nearer)."},
        {"aperture", &FocusTrack::aperture, 0.0, 4.0, "%.2f",
         "How much what is out of focus blurs: 1 is the clip's own lens, 0 all sharp."},
        {"blades", &FocusTrack::blades, 0.0, 12.0, "%.0f",
         "Aperture blades: 0 a round aperture, 3 or more a polygon (the bokeh's shape)."},
        {"rotation", &FocusTrack::rotation_deg, 0.0, 180.0, "%.0f deg",
         "Rotation of the polygonal aperture, in degrees."},
        {"rim (beta)", &FocusTrack::beta, 0.4, 10.0, "%.2f",
         "The blur disk's rim (paper eq. 2): larger gives bokeh a harder edge."},
        {"highlights", &FocusTrack::highlight_gain, 0.0, 8.0, "%.2f",
         "Brightens highlights in the blur into bokeh balls (0: off)."},
    };
    return lanes;
}

int focus_lane_index(const std::string& name) {
    const auto& lanes = focus_lanes();
    for (size_t i = 0; i < lanes.size(); ++i) {
        const LaneInfo& l = lanes[i];
        if (name == l.name || (name == "rim" && l.lane == &FocusTrack::beta) ||
            (name == "beta" && l.lane == &FocusTrack::beta) ||
            (name == "highlight_gain" && l.lane == &FocusTrack::highlight_gain) ||
            (name == "rotation_deg" && l.lane == &FocusTrack::rotation_deg))
            return static_cast<int>(i);
    }
    throw Error("unknown focus lane '" + name + "'");
}

const std::vector<EasingChoice>& easing_choices() {
    static const std::vector<EasingChoice> choices = {{Easing::Linear, "linear"},
                                                      {Easing::EaseInOut, "ease in-out"},
                                                      {Easing::EaseIn, "ease in"},
                                                      {Easing::EaseOut, "ease out"},
                                                      {Easing::Hold, "hold"}};
    return choices;
}

const char* easing_label(Easing e) {
    for (const EasingChoice& c : easing_choices())
        if (c.easing == e) return c.label;
    return "?";
}

void set_focus_key(StudioContext& ctx, const std::string& name, int frame, double value, Easing e) {
    const LaneInfo& l = focus_lanes()[focus_lane_index(name)];
    if (!std::isfinite(value)) throw Error("keyframe value for " + name + " is not a number");
    (ctx.doc.focus().*(l.lane)).set(frame, std::clamp(value, l.min, l.max), e);
    ctx.changed();
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
    ctx.doc.commit("Focus at frame " + std::to_string(frame));
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
    ctx.doc.commit("Track a point");
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
        const LaneInfo& info = lanes[i];
        float v = static_cast<float>(current[i]);
        ImGui::PushID(static_cast<int>(i));
        ImGui::SetNextItemWidth(200);
        if (ImGui::SliderFloat(info.name, &v, static_cast<float>(info.min),
                               static_cast<float>(info.max), info.format))
            ctx.guarded([&] { set_focus_key(ctx, info.name, ctx.frame, v, s.new_key_easing); });
        // A drag keys every frame it moves: one undo entry when it is let go.
        if (ImGui::IsItemDeactivatedAfterEdit())
            ctx.doc.commit(std::string("Set ") + info.name + " at frame " +
                           std::to_string(ctx.frame));
        if (ImGui::IsItemHovered())
            ImGui::SetTooltip("%s\nChanging it keys frame %d (Ctrl+click types a value).", info.tip,
                              ctx.frame);
        ImGui::SameLine();
        Lane& lane = ft.*(info.lane);
        const bool keyed = std::any_of(lane.keys.begin(), lane.keys.end(),
                                       [&](const Keyframe& k) { return k.frame == ctx.frame; });
        if (ImGui::SmallButton(keyed ? "del" : "key")) {
            if (keyed)
                lane.remove(ctx.frame);
            else
                lane.set(ctx.frame, current[i], s.new_key_easing);
            ctx.changed();
            ctx.doc.commit(std::string(keyed ? "Delete " : "Key ") + info.name + " at frame " +
                           std::to_string(ctx.frame));
        }
        item_tip(keyed ? "Delete this lane's key at the playhead."
                       : "Key this lane at the playhead with its current value.");
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
    if (ImGui::IsItemDeactivatedAfterEdit()) ctx.doc.commit("Tracking frames");
    item_tip(
        "The frames where the focus follows the tracked point (first, last); elsewhere the "
        "focus keys hold. Drag, or double-click to type.");
    if (ImGui::Button("Stop tracking")) {
        ft.track.reset();
        ctx.changed();
        ctx.doc.commit("Stop tracking");
    }
    item_tip("Forget the tracked point: the focus keys set the focus on every frame again.");
}

void draw_new_key_easing(FocusPanelState& s) {
    const auto& choices = easing_choices();
    if (ImGui::BeginCombo("new keys", easing_label(s.new_key_easing))) {
        for (const EasingChoice& c : choices)
            if (ImGui::Selectable(c.label, c.easing == s.new_key_easing))
                s.new_key_easing = c.easing;
        ImGui::EndCombo();
    }
    item_tip(
        "The easing of keys made from now on, from each key to the next: linear, ease "
        "in-out (smooth start and end), ease in (slow start), ease out (slow end), hold "
        "(jumps at the next key). Right-click a key in the timeline to change its own.");
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
    draw_new_key_easing(s);
    draw_lane_sliders(s, ctx);
    ImGui::Separator();
    using Pick = ViewerState::Pick;
    if (ImGui::Button(viewer.pick == Pick::Focus ? "click the viewer..." : "Click to focus"))
        arm_pick(viewer, ctx, Pick::Focus);
    item_tip(
        "Then click the viewer: the focus is keyed at the depth under the click, at the "
        "playhead (needs a fitted depth). Click again to cancel.");
    ImGui::SameLine();
    if (ImGui::Button(viewer.pick == Pick::Track ? "click the viewer..." : "Track a point"))
        arm_pick(viewer, ctx, Pick::Track);
    item_tip(
        "Then click the viewer: the focus follows that point of the scene through the clip "
        "(its atlas point). Click again to cancel.");
    if (ctx.doc.focus().track) draw_tracking(ctx);
    ImGui::TextWrapped(
        "Rack focus: key the focus at two frames (e.g. click the background at the "
        "first frame and the subject at a later one); ease in-out eases between them.");
}

}  // namespace refocus
