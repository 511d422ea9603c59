#pragma once
// Focus keyframes: per-parameter lanes of keys over frames, an optional focus target that follows
// an atlas point (the paper's focus tracking), and the preview lens they give at each frame.
// Stored in project.json's "focus" section.
#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

#include "render/preview.h"

namespace refocus {

struct DepthModel;
struct Project;

enum class Easing { Linear, EaseInOut, Hold, EaseIn, EaseOut };
// "linear", "ease_in_out", "hold", "ease_in", "ease_out" (project.json's names)
const char* easing_name(Easing e);
// The easing named `name` (easing_name's names); false when there is none.
bool parse_easing_name(const std::string& name, Easing& out);

struct Keyframe {
    int frame = 0;
    double value = 0.0;
    Easing easing = Easing::Linear;  // of the segment from this key to the next
};

// Keys sorted by frame, at most one per frame. Between keys k and k+1, with s = (frame − f_k) /
// (f_{k+1} − f_k): Linear v_k + s·Δv; EaseInOut v_k + (3s² − 2s³)·Δv (smoothstep); EaseIn
// v_k + s²·Δv and EaseOut v_k + (1 − (1 − s)²)·Δv (Penner's quadratic easing); Hold v_k.
// Before the first key and after the last the nearest key's value holds.
struct Lane {
    std::vector<Keyframe> keys;
    double eval(double frame, double fallback) const;                   // fallback: no keys
    void set(int frame, double value, Easing easing = Easing::Linear);  // replaces that frame's
    bool remove(int frame);  // false if no key at `frame`
    bool empty() const { return keys.empty(); }
};

// Focus on a point of an atlas: layer (DepthModel::Background 0 / Foreground 1), atlas
// coordinates (u, v) ∈ [−1, 1]², for frames from_frame..to_frame inclusive.
struct FocusTarget {
    int layer = 0;
    float u = 0.0f, v = 0.0f;
    int from_frame = 0, to_frame = 0;
};

struct FocusTrack {
    static constexpr int kVersion = 1;
    Lane focus;     // inverse depth in focus (DepthModel units)
    Lane aperture;  // px of blur per unit of inverse depth (1: as shot, 0: sharp)
    Lane blades;    // 0: circle, 3..64: polygon (rounded)
    Lane rotation_deg;
    Lane beta;  // disk kernel rim (paper eq. 2)
    Lane highlight_gain;
    double highlight_threshold = 1.0;
    std::optional<FocusTarget> track;

    // The lens at `frame`. Empty lanes: focus = the clip's own focus depth->focus[frame] (0
    // without depth), aperture 0 (sharp), blades 0, rotation 0, beta 2, gain 0. While `track`
    // covers the frame (and depth is given), focus = depth->depth_at_atlas(track) at that frame.
    // Values are clamped into check_preview_lens's ranges (non-finite ones take the default).
    PreviewLens lens_at(int frame, const DepthModel* depth) const;

    nlohmann::json to_json() const;
    // Validates every field; refocus::Error names `label` and the field ("aperture[2].frame").
    static FocusTrack from_json(const nlohmann::json& j, const std::string& label);
};

// project.json "focus" section (an empty track when absent).
FocusTrack read_focus(const Project& project);
void write_focus(Project& project, const FocusTrack& track);  // and saves project.json

}  // namespace refocus
