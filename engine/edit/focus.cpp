// Focus keyframes and tracking; see focus.h.
#include "edit/focus.h"

#include <algorithm>
#include <cmath>

#include "edit/depth.h"
#include "project/project.h"
#include "util/error.h"

namespace refocus {

using nlohmann::json;

const char* easing_name(Easing e) {
    switch (e) {
        case Easing::Linear:
            return "linear";
        case Easing::EaseInOut:
            return "ease_in_out";
        case Easing::Hold:
            return "hold";
        case Easing::EaseIn:
            return "ease_in";
        case Easing::EaseOut:
            return "ease_out";
    }
    return "?";
}

bool parse_easing_name(const std::string& name, Easing& out) {
    for (Easing e :
         {Easing::Linear, Easing::EaseInOut, Easing::Hold, Easing::EaseIn, Easing::EaseOut})
        if (name == easing_name(e)) {
            out = e;
            return true;
        }
    return false;
}

double Lane::eval(double frame, double fallback) const {
    if (keys.empty()) return fallback;
    if (frame <= keys.front().frame) return keys.front().value;
    if (frame >= keys.back().frame) return keys.back().value;
    auto next = std::upper_bound(keys.begin(), keys.end(), frame,
                                 [](double f, const Keyframe& k) { return f < k.frame; });
    const Keyframe& a = *(next - 1);
    const Keyframe& b = *next;
    const double s = (frame - a.frame) / double(b.frame - a.frame);
    switch (a.easing) {
        case Easing::Hold:
            return a.value;
        case Easing::EaseInOut:
            return a.value + s * s * (3 - 2 * s) * (b.value - a.value);
        // Quadratic ease-in and ease-out: R. Penner, "Motion, Tweening, and Easing", ch. 7 of
        // Programming Macromedia Flash MX (2002), easeInQuad and easeOutQuad.
        case Easing::EaseIn:
            return a.value + s * s * (b.value - a.value);
        case Easing::EaseOut:
            return a.value + s * (2 - s) * (b.value - a.value);
        case Easing::Linear:
            break;
    }
    return a.value + s * (b.value - a.value);
}

void Lane::set(int frame, double value, Easing easing) {
    auto it = std::lower_bound(keys.begin(), keys.end(), frame,
                               [](const Keyframe& k, int f) { return k.frame < f; });
    if (it != keys.end() && it->frame == frame)
        *it = {frame, value, easing};
    else
        keys.insert(it, {frame, value, easing});
}

bool Lane::remove(int frame) {
    auto it =
        std::find_if(keys.begin(), keys.end(), [&](const Keyframe& k) { return k.frame == frame; });
    if (it == keys.end()) return false;
    keys.erase(it);
    return true;
}

PreviewLens FocusTrack::lens_at(int frame, const DepthModel* depth) const {
    auto value = [&](const Lane& lane, double fallback, double lo, double hi) {
        const double v = lane.eval(frame, fallback);
        return std::isfinite(v) ? std::clamp(v, lo, hi) : fallback;
    };
    const double inf = 1e30;
    double own = 0.0;
    if (depth && depth->frames() > 0) own = depth->focus[std::clamp(frame, 0, depth->frames() - 1)];
    PreviewLens lens;
    lens.focus = value(focus, own, -inf, inf);
    if (track && depth && frame >= track->from_frame && frame <= track->to_frame) {
        const double d = depth->depth_at_atlas(track->layer, track->u, track->v, frame);
        if (std::isfinite(d)) lens.focus = d;
    }
    lens.aperture = value(aperture, 0.0, 0.0, 1e6);
    const long blades_n = std::lround(value(blades, 0.0, 0.0, 64.0));
    lens.blades = blades_n < 3 ? 0 : int(blades_n);
    lens.rotation_deg = value(rotation_deg, 0.0, -inf, inf);
    lens.beta = value(beta, 2.0, 0.37, 1e3);  // > 1/e
    lens.highlight_gain = value(highlight_gain, 0.0, 0.0, 1e6);
    lens.highlight_threshold = std::isfinite(highlight_threshold) ? highlight_threshold : 1.0;
    return lens;
}

namespace {

const std::pair<const char*, Lane FocusTrack::*> kLanes[] = {
    {"focus", &FocusTrack::focus},   {"aperture", &FocusTrack::aperture},
    {"blades", &FocusTrack::blades}, {"rotation_deg", &FocusTrack::rotation_deg},
    {"beta", &FocusTrack::beta},     {"highlight_gain", &FocusTrack::highlight_gain}};

}  // namespace

json FocusTrack::to_json() const {
    json j = {{"version", kVersion}, {"highlight_threshold", highlight_threshold}};
    for (const auto& [name, lane] : kLanes) {
        json keys = json::array();
        for (const Keyframe& k : (this->*lane).keys)
            keys.push_back(
                {{"frame", k.frame}, {"value", k.value}, {"easing", easing_name(k.easing)}});
        j[name] = keys;
    }
    j["track"] = track ? json{{"layer", track->layer},
                              {"u", track->u},
                              {"v", track->v},
                              {"from_frame", track->from_frame},
                              {"to_frame", track->to_frame}}
                       : json(nullptr);
    return j;
}

FocusTrack FocusTrack::from_json(const json& j, const std::string& label) {
    auto bad = [&](const std::string& field, const std::string& what) -> void {
        throw Error(file_error(label, "focus field '" + field + "': " + what));
    };
    auto number = [&](const json& o, const char* key, const std::string& field) {
        if (!o.contains(key)) bad(field, "missing");
        if (!o[key].is_number() || !std::isfinite(o[key].get<double>()))
            bad(field, "must be a finite number");
        return o[key].get<double>();
    };
    auto integer = [&](const json& o, const char* key, const std::string& field) {
        if (!o.contains(key)) bad(field, "missing");
        if (!o[key].is_number_integer()) bad(field, "must be an integer");
        return o[key].get<int>();
    };
    if (!j.is_object()) bad("focus", "must be an object");
    FocusTrack ft;
    if (j.contains("version")) {
        const int v = integer(j, "version", "version");
        if (v > kVersion || v < 1)
            bad("version", std::to_string(v) + " (this Refocus reads focus version " +
                               std::to_string(kVersion) + ")");
    }
    if (j.contains("highlight_threshold"))
        ft.highlight_threshold = number(j, "highlight_threshold", "highlight_threshold");
    for (const auto& [name, lane] : kLanes) {
        if (!j.contains(name)) continue;
        const json& keys = j[name];
        if (!keys.is_array()) bad(name, "must be an array of keys");
        for (size_t i = 0; i < keys.size(); ++i) {
            const std::string f = std::string(name) + "[" + std::to_string(i) + "]";
            const json& k = keys[i];
            if (!k.is_object()) bad(f, "must be an object {frame, value, easing}");
            Keyframe key;
            key.frame = integer(k, "frame", f + ".frame");
            if (key.frame < 0) bad(f + ".frame", "must be >= 0");
            key.value = number(k, "value", f + ".value");
            const std::string e = k.contains("easing") && k["easing"].is_string()
                                      ? k["easing"].get<std::string>()
                                      : (k.contains("easing") ? "?" : "linear");
            if (!parse_easing_name(e, key.easing))
                bad(f + ".easing",
                    "unknown easing (use linear, ease_in_out, ease_in, ease_out or hold)");
            Lane& l = ft.*lane;
            if (std::any_of(l.keys.begin(), l.keys.end(),
                            [&](const Keyframe& o) { return o.frame == key.frame; }))
                bad(f + ".frame", "two keys at frame " + std::to_string(key.frame));
            l.set(key.frame, key.value, key.easing);
        }
    }
    if (j.contains("track") && !j["track"].is_null()) {
        const json& t = j["track"];
        if (!t.is_object()) bad("track", "must be an object or null");
        FocusTarget tg;
        tg.layer = integer(t, "layer", "track.layer");
        if (tg.layer != 0 && tg.layer != 1)
            bad("track.layer", "must be 0 (background) or 1 (foreground)");
        tg.u = float(number(t, "u", "track.u"));
        tg.v = float(number(t, "v", "track.v"));
        if (std::fabs(tg.u) > 1 || std::fabs(tg.v) > 1)
            bad("track.u/v", "atlas coordinates must be in [-1, 1]");
        tg.from_frame = integer(t, "from_frame", "track.from_frame");
        tg.to_frame = integer(t, "to_frame", "track.to_frame");
        if (tg.to_frame < tg.from_frame) bad("track.to_frame", "must be >= from_frame");
        ft.track = tg;
    }
    return ft;
}

FocusTrack read_focus(const Project& p) {
    if (!p.sections.contains("focus")) return {};
    return FocusTrack::from_json(p.sections.at("focus"), p.project_file().string());
}

void write_focus(Project& p, const FocusTrack& track) {
    p.sections["focus"] = track.to_json();
    p.save_merged({"focus"});
}

}  // namespace refocus
