#include "key_lanes.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <optional>

#include "focus_panel.h"
#include "item_tip.h"
#include "studio_context.h"
#include "util/error.h"

namespace refocus {

namespace {

constexpr const char* kKeyMenu = "key menu";

Lane& lane_of(FocusTrack& t, int lane) {
    return t.*(focus_lanes()[lane].lane);
}

Keyframe* find_key(FocusTrack& t, const KeyRef& r) {
    if (r.lane < 0 || r.lane >= static_cast<int>(focus_lanes().size())) return nullptr;
    for (Keyframe& k : lane_of(t, r.lane).keys)
        if (k.frame == r.frame) return &k;
    return nullptr;
}

bool contains(const std::vector<KeyRef>& v, const KeyRef& r) {
    return std::find(v.begin(), v.end(), r) != v.end();
}

std::string keys_label(const std::string& verb, size_t n) {
    return verb + (n == 1 ? " key" : " " + std::to_string(n) + " keys");
}

// Where the lanes are on screen: a label column, then one row per lane; frame f spans
// [f, f + 1) of the clip's width.
struct LaneGeometry {
    ImVec2 origin;
    float label_w = 110.0f, row_h = 18.0f, lane_w = 1.0f;
    int frames = 1, rows = 0;
    float x_of(double frame) const {
        return origin.x + label_w + static_cast<float>((frame + 0.5) / frames) * lane_w;
    }
    int frame_at(float x) const {
        const int f = static_cast<int>(std::floor((x - origin.x - label_w) / lane_w * frames));
        return std::clamp(f, 0, frames - 1);
    }
    int row_at(float y) const { return static_cast<int>(std::floor((y - origin.y) / row_h)); }
};

// The key drawn under screen point p (within 6 px), if any.
std::optional<KeyRef> key_at(FocusTrack& t, const LaneGeometry& g, ImVec2 p) {
    const int row = g.row_at(p.y);
    if (row < 0 || row >= g.rows) return std::nullopt;
    std::optional<KeyRef> best;
    float best_d = 6.0f;
    for (const Keyframe& k : lane_of(t, row).keys) {
        const float d = std::abs(g.x_of(k.frame) - p.x);
        if (d <= best_d) best = KeyRef{row, k.frame}, best_d = d;
    }
    return best;
}

void delete_selected(KeyLaneState& s, StudioContext& ctx) {
    const int n = remove_keys(ctx.doc.focus(), s.selected);
    s.selected.clear();
    if (n == 0) return;
    ctx.changed();
    ctx.doc.commit(keys_label("Delete", n));
}

void copy_selected(KeyLaneState& s, StudioContext& ctx) {
    if (s.selected.empty()) return;
    int first = INT_MAX;
    for (const KeyRef& r : s.selected) first = std::min(first, r.frame);
    s.clipboard.clear();
    for (const KeyRef& r : s.selected)
        if (const Keyframe* k = find_key(ctx.doc.focus(), r))
            s.clipboard.push_back({KeyRef{r.lane, r.frame - first}, *k});
    ctx.info = "copied " + keys_label("", s.clipboard.size()).substr(1);
}

// Pastes the copied keys with the first at the playhead; those past the clip's end are left out.
void paste_at_playhead(KeyLaneState& s, StudioContext& ctx, int frames) {
    if (s.clipboard.empty()) return;
    std::vector<KeyRef> pasted;
    int left_out = 0;
    for (const auto& [rel, key] : s.clipboard) {
        const int f = ctx.frame + rel.frame;
        if (f > frames - 1) {
            ++left_out;
            continue;
        }
        lane_of(ctx.doc.focus(), rel.lane).set(f, key.value, key.easing);
        pasted.push_back({rel.lane, f});
    }
    if (left_out > 0)
        ctx.info = std::to_string(left_out) + " copied key(s) would fall after the clip's end";
    if (pasted.empty()) return;
    s.selected = pasted;
    ctx.changed();
    ctx.doc.commit(keys_label("Paste", pasted.size()));
}

// Delete / Backspace, Ctrl+C, Ctrl+V and Escape while the timeline has the keyboard.
void lane_shortcuts(KeyLaneState& s, StudioContext& ctx, int frames) {
    const ImGuiIO& io = ImGui::GetIO();
    if (!ImGui::IsWindowFocused() || io.WantTextInput) return;
    if (ImGui::IsKeyPressed(GLFW_KEY_DELETE) || ImGui::IsKeyPressed(GLFW_KEY_BACKSPACE))
        delete_selected(s, ctx);
    if (io.KeyCtrl && ImGui::IsKeyPressed(GLFW_KEY_C)) copy_selected(s, ctx);
    if (io.KeyCtrl && ImGui::IsKeyPressed(GLFW_KEY_V)) paste_at_playhead(s, ctx, frames);
    if (ImGui::IsKeyPressed(GLFW_KEY_ESCAPE)) s.selected.clear();
}

// Right-click menu of one key: the easing (of the selected keys), its value, delete.
void draw_key_menu(KeyLaneState& s, StudioContext& ctx) {
    if (!ImGui::BeginPopup(kKeyMenu)) return;
    Keyframe* k = find_key(ctx.doc.focus(), s.menu_key);
    if (!k) {  // undone or deleted meanwhile
        ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
        return;
    }
    const LaneInfo& info = focus_lanes()[s.menu_key.lane];
    ImGui::TextDisabled("%s key at frame %d", info.name, k->frame);
    if (s.selected.size() > 1)
        ImGui::TextDisabled("easing and delete: the %zu selected keys", s.selected.size());
    ImGui::Separator();
    for (const EasingChoice& c : easing_choices())
        if (ImGui::MenuItem(c.label, nullptr, k->easing == c.easing)) {
            for (const KeyRef& r : s.selected)
                if (Keyframe* sk = find_key(ctx.doc.focus(), r)) sk->easing = c.easing;
            ctx.changed();
            ctx.doc.commit(std::string("Easing: ") + c.label);
        }
    ImGui::Separator();
    float v = static_cast<float>(k->value);
    ImGui::SetNextItemWidth(140);
    const float lo = static_cast<float>(info.min), hi = static_cast<float>(info.max);
    if (ImGui::DragFloat("value", &v, (hi - lo) / 300.0f, lo, hi, info.format)) {
        k->value = std::clamp(static_cast<double>(v), info.min, info.max);
        ctx.changed();
    }
    if (ImGui::IsItemDeactivatedAfterEdit())
        ctx.doc.commit(std::string("Set ") + info.name + " key value");
    item_tip("Drag to change this key's value, or double-click to type one.");
    if (ImGui::MenuItem("Delete", "Del")) delete_selected(s, ctx);
    ImGui::EndPopup();
}

void draw_key_tooltip(StudioContext& ctx, const KeyRef& r) {
    const Keyframe* k = find_key(ctx.doc.focus(), r);
    if (!k) return;
    const LaneInfo& info = focus_lanes()[r.lane];
    char value[64];
    std::snprintf(value, sizeof value, info.format, k->value);
    ImGui::SetTooltip(
        "%s key\nframe %d\nvalue %s\n%s to the next key\n(drag to move, right-click for easing "
        "and value)",
        info.name, k->frame, value, easing_label(k->easing));
}

// Labels, lane backgrounds, each lane's curve, the keys (Hold keys square), the tracked range
// and the playhead.
void draw_lanes(const KeyLaneState& s, StudioContext& ctx, const LaneGeometry& g,
                const std::optional<KeyRef>& hovered) {
    ImDrawList* dl = ImGui::GetWindowDrawList();
    const auto& lanes = focus_lanes();
    for (int i = 0; i < g.rows; ++i) {
        const float y = g.origin.y + i * g.row_h;
        const float x0 = g.origin.x + g.label_w;
        dl->AddText(ImVec2(g.origin.x, y + 2), IM_COL32(200, 200, 200, 255), lanes[i].name);
        dl->AddRectFilled(ImVec2(x0, y + 1), ImVec2(x0 + g.lane_w, y + g.row_h - 1),
                          IM_COL32(40, 40, 46, 255));
        const Lane& lane = ctx.doc.focus().*(lanes[i].lane);
        if (lane.keys.size() >= 2) {  // the value between the keys, scaled to the row
            const double span = lanes[i].max - lanes[i].min;
            auto y_of = [&](double v) {
                const double u = std::clamp((v - lanes[i].min) / span, 0.0, 1.0);
                return y + g.row_h - 3.0f - static_cast<float>(u) * (g.row_h - 6.0f);
            };
            std::vector<ImVec2> pts;
            for (float x = 0; x <= g.lane_w; x += 3.0f) {
                const double f = x / g.lane_w * g.frames - 0.5;
                pts.push_back(ImVec2(x0 + x, y_of(lane.eval(f, 0.0))));
            }
            dl->AddPolyline(pts.data(), static_cast<int>(pts.size()), IM_COL32(240, 190, 60, 90), 0,
                            1.0f);
        }
        for (const Keyframe& k : lane.keys) {
            const KeyRef ref{i, k.frame};
            const bool sel = contains(s.selected, ref), hot = hovered && *hovered == ref;
            const ImU32 fill = sel   ? IM_COL32(255, 255, 255, 255)
                               : hot ? IM_COL32(255, 220, 120, 255)
                                     : IM_COL32(240, 190, 60, 255);
            const float cx = g.x_of(k.frame), cy = y + g.row_h * 0.5f, r = 5.0f;
            if (k.easing == Easing::Hold)
                dl->AddRectFilled(ImVec2(cx - r + 1, cy - r + 1), ImVec2(cx + r - 1, cy + r - 1),
                                  fill);
            else
                dl->AddQuadFilled(ImVec2(cx, cy - r), ImVec2(cx + r, cy), ImVec2(cx, cy + r),
                                  ImVec2(cx - r, cy), fill);
            if (sel)
                dl->AddQuad(ImVec2(cx, cy - r - 2), ImVec2(cx + r + 2, cy), ImVec2(cx, cy + r + 2),
                            ImVec2(cx - r - 2, cy), IM_COL32(240, 190, 60, 255), 1.5f);
        }
    }
    if (ctx.doc.focus().track) {
        const auto& tr = *ctx.doc.focus().track;
        const float y = g.origin.y + 0.5f * g.row_h;
        dl->AddLine(ImVec2(g.x_of(tr.from_frame), y), ImVec2(g.x_of(tr.to_frame), y),
                    IM_COL32(90, 200, 255, 200), 3.0f);
    }
    const float x = g.x_of(ctx.frame);
    dl->AddLine(ImVec2(x, g.origin.y), ImVec2(x, g.origin.y + g.rows * g.row_h),
                IM_COL32(255, 80, 80, 255), 2.0f);
}

// A press on a key selects it (Shift: adds or removes it) and starts a drag of the selection;
// a press elsewhere moves the playhead. Each drag frame moves the keys from where they were at
// the press; the release commits the move as one undo entry.
void handle_mouse(KeyLaneState& s, StudioContext& ctx, const LaneGeometry& g,
                  const std::optional<KeyRef>& under) {
    const ImGuiIO& io = ImGui::GetIO();
    const float mx = ImGui::GetMousePos().x;
    if (ImGui::IsItemActivated()) {
        if (under) {
            if (!io.KeyShift && !contains(s.selected, *under))
                s.selected = {*under};
            else if (io.KeyShift && contains(s.selected, *under))
                s.selected.erase(std::find(s.selected.begin(), s.selected.end(), *under));
            else if (io.KeyShift)
                s.selected.push_back(*under);
            s.pressed_key = contains(s.selected, *under);
            s.pressed = *under;
            s.drag_from = ctx.doc.focus();
            s.drag_keys = s.selected;
            s.press_x = mx;
            s.drag_delta = 0;
        } else {
            if (!io.KeyShift) s.selected.clear();
            s.scrubbing = true;
        }
    }
    if (ImGui::IsItemActive()) {
        if (s.scrubbing) ctx.set_frame(g.frame_at(mx));
        if (s.pressed_key) {
            const int delta = static_cast<int>(std::lround((mx - s.press_x) / g.lane_w * g.frames));
            FocusTrack moved = s.drag_from;
            std::vector<KeyRef> at = move_keys(moved, s.drag_keys, delta, g.frames);
            const int clamped = at.empty() ? 0 : at[0].frame - s.drag_keys[0].frame;
            if (clamped != s.drag_delta) {
                s.drag_delta = clamped;
                s.selected = std::move(at);
                ctx.doc.focus() = std::move(moved);
                ctx.changed();
            }
        }
    }
    if (ImGui::IsItemDeactivated()) {
        if (s.pressed_key && s.drag_delta != 0)
            ctx.doc.commit(keys_label("Move", s.drag_keys.size()));
        else if (s.pressed_key && !io.KeyShift)
            s.selected = {s.pressed};  // a click in a selection picks that key
        s.pressed_key = s.scrubbing = false;
        s.drag_delta = 0;
    }
    if (under && ImGui::IsItemHovered() && ImGui::IsMouseClicked(1)) {
        if (!contains(s.selected, *under)) s.selected = {*under};
        s.menu_key = *under;
        ImGui::OpenPopup(kKeyMenu);
    }
}

}  // namespace

std::vector<KeyRef> move_keys(FocusTrack& track, const std::vector<KeyRef>& keys_in, int delta,
                              int frames) {
    std::vector<KeyRef> keys;
    for (const KeyRef& r : keys_in)
        if (!contains(keys, r)) keys.push_back(r);
    if (keys.empty()) return {};
    std::vector<Keyframe> taken;
    int lo = INT_MAX, hi = INT_MIN;
    for (const KeyRef& r : keys) {
        const Keyframe* k = find_key(track, r);
        if (!k)
            throw Error(std::string("no ") + focus_lanes().at(r.lane).name + " key at frame " +
                        std::to_string(r.frame));
        taken.push_back(*k);
        lo = std::min(lo, r.frame);
        hi = std::max(hi, r.frame);
    }
    delta = std::clamp(delta, -lo, std::max(-lo, frames - 1 - hi));  // every key stays in the clip
    for (const KeyRef& r : keys) lane_of(track, r.lane).remove(r.frame);
    std::vector<KeyRef> moved;
    for (size_t i = 0; i < keys.size(); ++i) {
        const KeyRef to{keys[i].lane, keys[i].frame + delta};
        lane_of(track, to.lane).set(to.frame, taken[i].value, taken[i].easing);
        moved.push_back(to);
    }
    return moved;
}

int remove_keys(FocusTrack& track, const std::vector<KeyRef>& keys) {
    int n = 0;
    for (const KeyRef& r : keys)
        if (r.lane >= 0 && r.lane < static_cast<int>(focus_lanes().size()))
            n += lane_of(track, r.lane).remove(r.frame);
    return n;
}

void move_key(StudioContext& ctx, const std::string& lane, int from, int to) {
    if (!ctx.doc.is_open()) throw Error("no project is open");
    move_keys(ctx.doc.focus(), {{focus_lane_index(lane), from}}, to - from,
              ctx.doc.project().frames);
    ctx.changed();
    ctx.doc.commit("Move key");
}

void delete_key(StudioContext& ctx, const std::string& lane, int frame) {
    if (!ctx.doc.is_open()) throw Error("no project is open");
    if (remove_keys(ctx.doc.focus(), {{focus_lane_index(lane), frame}}) == 0)
        throw Error("no " + lane + " key at frame " + std::to_string(frame));
    ctx.changed();
    ctx.doc.commit("Delete key");
}

void draw_key_lanes(KeyLaneState& s, StudioContext& ctx, ImVec2 origin, ImVec2 size) {
    if (!ctx.source) return;
    LaneGeometry g;
    g.origin = origin;
    g.frames = ctx.source->frames();
    g.rows = static_cast<int>(focus_lanes().size());
    g.lane_w = std::max(size.x - g.label_w, 1.0f);
    // Keys gone (undo, another edit) leave the selection.
    FocusTrack& t = ctx.doc.focus();
    s.selected.erase(std::remove_if(s.selected.begin(), s.selected.end(),
                                    [&](const KeyRef& r) { return !find_key(t, r); }),
                     s.selected.end());
    ImGui::SetCursorScreenPos(ImVec2(origin.x + g.label_w, origin.y));
    ImGui::InvisibleButton("lanes", ImVec2(g.lane_w, g.rows * g.row_h));
    const bool hovered = ImGui::IsItemHovered();
    const std::optional<KeyRef> under =
        hovered ? key_at(t, g, ImGui::GetMousePos()) : std::optional<KeyRef>();
    handle_mouse(s, ctx, g, under);
    if (under && !s.pressed_key) draw_key_tooltip(ctx, *under);
    draw_lanes(s, ctx, g, under);
    lane_shortcuts(s, ctx, g.frames);
    draw_key_menu(s, ctx);
}

}  // namespace refocus
