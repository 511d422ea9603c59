#include "fit/settings.h"

#include <cmath>
#include <cstdio>
#include <functional>
#include <sstream>
#include <variant>

#include <nlohmann/json.hpp>

#include "fit/fast_model.h"
#include "fit/fit_engine.h"
#include "fit/fit_setup.h"
#include "fit/paper_model.h"
#include "fit/perframe.h"
#include "radius/stack_coc.h"
#include "util/error.h"

namespace refocus {

namespace {

// One setting bound to a member of options struct S.
template <class S>
struct Field {
    const char* name;
    std::variant<double S::*, int S::*, int64_t S::*, bool S::*, std::string S::*> member;
    double lo, hi;  // numbers: the valid range (inclusive)
    const char* help;
    std::vector<std::string> choices = {};  // strings: the valid values
    const char* def_text = nullptr;         // the default where the member's initialiser is not it
};

constexpr double kInf = 1e300;

const std::vector<Field<FitOptions>>& fit_fields() {
    using O = FitOptions;
    static const std::vector<Field<O>> f = {
        {"fit.w_reco", &O::w_reco, 0, 1e6,
         "weight of the reconstruction loss (paper eq. 4, lambda1)"},
        {"fit.ms_ssim_share", &O::ms_ssim_share, 0, 1,
         "share of (1 - MS-SSIM) in L_reco; the rest is L1"},
        {"fit.lr_floor", &O::lr_floor, 0, 1,
         "the learning rate decays (cosine) to this share of its own"},
        {"fit.checkpoint_seconds", &O::checkpoint_seconds, 1, 1e6,
         "training seconds between checkpoints"},
        {"fit.robust_c", &O::robust_c, 0, 1e6,
         "robust weights: Geman-McClure scale, times the frame's median residual (0: off)"},
        {"fit.robust_warmup", &O::robust_warmup, 0, 1e9, "steps before the robust weights apply"},
        {"fit.fallback_k", &O::fallback_k, 0, 1e6,
         "the input shows through from this many times the frame's median residual"},
        {"fit.fallback_min", &O::fallback_min, 0, 1, "... and from at least this residual (sRGB)"},
        {"fit.fallback_change", &O::fallback_change, 0, 1e3,
         "the input shows through where the residual passes 0.8 x the measured noise plus this "
         "share of what the model changes over its reblur, plus fit.fallback_floor; 0: the "
         "median rule (fit.fallback_k, fit.fallback_min)"},
        {"fit.fallback_floor", &O::fallback_floor, 0, 1,
         "the evidence rule's least residual (sRGB) before the input shows through"},
        {"fit.trusted_residual", &O::trusted_residual, 0, 100,
         "where the fit is trusted (fit.explained_rms), the evidence rule's floor rises to this "
         "many times the clip's residual RMS over the noise (0: off)"},
        {"fit.fallback_frames", &O::fallback_frames, 0, 12,
         "the fallback is smooth in time: grown over +-n frames, then averaged over +-n"},
        {"fit.lock_low_px", &O::lock_low_px, 0, 64,
         "the plate takes the input's content below this Gaussian scale (px); 0: off"},
        {"fit.explained_rms", &O::explained_rms, 0, 255,
         "the fit explains the clip where its reblur residual's RMS over the noise is under "
         "this (8-bit levels; trusted fully below, not from 1.4x): there the low-frequency lock "
         "reads the model's reblur, not its sharp frame (0: never)"},
        {"fit.trusted_blur_px", &O::trusted_blur_px, 0, 64,
         "where the fit is trusted, the model also replaces pixels no frame saw sharper where "
         "the blur reaches twice this (px), none under it (0, the default: never; 1 measured: "
         "gains where the lens is the model's, loses where the radius or lens is wrong)"},
        {"fit.trust_seen_px", &O::trust_seen_px, 0, 64,
         "the model restores a pixel fully where some frame saw it blurred by at most this "
         "radius (px), not from twice that; elsewhere the output is the shot (0: off)"},
        {"fit.sharper_view_px", &O::sharper_view_px, 0, 64,
         "the model replaces a pixel only where some frame saw it sharper than this frame did, "
         "by more than this (px), fully from twice that (0: off)"},
        {"fit.focus_moved_px", &O::focus_moved_px, 0, 64,
         "where focus moved over a point by at least this (px: the largest radius seen less the "
         "least), the sharper-view threshold is fit.sharper_view_moved_px (0: off)"},
        {"fit.sharper_view_moved_px", &O::sharper_view_moved_px, 0, 64,
         "the sharper-view threshold (px) where focus moved over the point"},
        {"fit.focus_travel_px", &O::focus_travel_px, 0, 64,
         "where a layer's focus moved as a whole by at least this (px: the range of its median "
         "radius over frames), a point passed over by half that travel counts as moved (0: off)"},
        {"fit.keep_focus_px", &O::keep_focus_px, 0, 8,
         "where no blur of at least this radius (px) reaches a pixel, the output is the shot "
         "(0: off)"},
        {"fit.layer_radius", &O::layer_radius, 0, 1,
         "two layers: each blurred with its own radius, not the visible surface's"},
        {"fit.crop_px", &O::crop_px, 0, 1e5,
         "a step renders, reblurs and scores a crop of about this many px a side of each frame "
         "(an axis no longer: whole); 0: whole frames; at least 32"},
        {"fit.crop_lr_power", &O::crop_lr_power, 0, 2,
         "a crop step's learning rates times its share of the frame to this power"},
    };
    return f;
}

const std::vector<Field<FitSetupOptions>>& setup_fields() {
    using O = FitSetupOptions;
    static const std::vector<Field<O>> f = {
        {"fit.kernel",
         &O::kernel,
         0,
         0,
         "the lens blur layer's kernel: pillbox (seed 001 eq. 1.13) or disk (paper eq. 2, beta 2)",
         {"pillbox", "disk"}},
        {"fast.atlas_scale", &O::atlas_scale, 0, 4,
         "atlas texels per frame pixel (0: chosen from the radius source and the camera)"},
        {"fit.memory_mb", &O::memory_mb, 0, 1e9,
         "a clip whose frames take more than this (MB, float) streams its per-frame arrays "
         "through file mappings in the project's work/ folder"},
        {"fit.clip_cache", &O::clip_cache, 0, 1,
         "a clip whose arrays stream through file mappings keeps them in work/clip/ for the next "
         "command (export, the studio, --resume) to open at once; 0: made again each time"},
        {"prepare.proxy_width", &O::proxy_width, 0, 1e5,
         "flow, camera motion, masks and the radius estimate run on frames at most this wide "
         "(px), their results scaled up; 0: at the clip's size"},
    };
    return f;
}

const std::vector<Field<FastModelOptions>>& fast_fields() {
    using O = FastModelOptions;
    static const std::vector<Field<O>> f = {
        {"fast.lr_atlas", &O::lr_atlas, 0, 10, "atlas texels' learning rate (Adam)"},
        {"fast.lr_warp", &O::lr_warp, 0, 10, "residual warps' learning rate, px a step (Adam)"},
        {"fast.lr_alpha", &O::lr_alpha, 0, 10, "alpha logits' learning rate (Adam)"},
        {"fast.alpha_shared_lr", &O::alpha_shared_lr, 0, 100,
         "the shared matte's learning rate, times lr_alpha"},
        {"fast.w_tv", &O::w_tv, 0, 1e3, "atlas total variation weight"},
        {"fast.tv_radius_cap", &O::tv_radius_cap, 1, 1e3,
         "TV factor cap on texels seen at one radius in every frame (1: uniform TV)"},
        {"fast.tv_radius_gain", &O::tv_radius_gain, 0, 1e3, "... TV factor per px of that radius"},
        {"fast.tv_radius_spread", &O::tv_radius_spread, 0, 1e3,
         "... where the radii seen vary by less (px)"},
        {"fast.tv_radius_fade", &O::tv_radius_fade, 0, 1e3,
         "... and the radius is under this (px)"},
        {"fast.tv_radius_layers", &O::tv_radius_layers, 0, 3,
         "... on which atlases: 1 background, 2 foreground, 3 both"},
        {"fast.w_warp", &O::w_warp, 0, 1e3, "residual warp smoothness weight"},
        {"fast.w_temporal", &O::w_temporal, 0, 1e3,
         "neighbouring frames' residual warps and mattes agree"},
        {"fast.w_alpha_residual", &O::w_alpha_residual, 0, 1e3,
         "L1 on the per-frame alpha residual"},
        {"fast.w_bootstrap", &O::w_bootstrap, 0, 1e3, "alpha to the masks at the start"},
        {"fast.bootstrap_halflife", &O::bootstrap_halflife, 1, 1e9,
         "... halving every this many steps"},
        {"fast.warp_cell_px", &O::warp_cell_px, 4, 1024, "residual warp grid spacing (px)"},
        {"fast.flow_warp", &O::flow_warp, 0, 1,
         "a moving camera's background warps start from the optical flow (parallax)"},
        {"fast.flow_warp_cell_px", &O::flow_warp_cell_px, 2, 1024, "... on a grid this fine (px)"},
        {"fast.parallax", &O::parallax, 0, 1,
         "plane + parallax on a moving camera's background: one depth field for the clip"},
        {"fast.parallax_evidence", &O::parallax_evidence, 0, 1,
         "... where the field fitted to half the frame pairs predicts the other half's flow "
         "better by this share (0: whenever the camera moves)"},
        {"fast.parallax_travel_px", &O::parallax_travel_px, 0, 1e5,
         "... where the view travels at least this far over the clip (frame px)"},
        {"fast.parallax_cell_px", &O::parallax_cell_px, 2, 1024, "... on a grid this fine (px)"},
        {"fast.parallax_homography", &O::parallax_homography, 0, 1,
         "... with each frame's homography corrected by an affine map fitted with it"},
        {"fast.lr_parallax", &O::lr_parallax, 0, 100, "... its learning rate (px per step)"},
        {"fast.lr_epipole", &O::lr_epipole, 0, 100, "... the epipoles' learning rate"},
        {"fast.w_parallax", &O::w_parallax, 0, 1e3, "... its smoothness weight"},
        {"fast.align_rounds", &O::align_rounds, 0, 20,
         "ECC alignment rounds at initialisation (0: off)"},
        {"fast.align_width", &O::align_width, 0, 1e5,
         "... on frames shrunk to at most this wide (px; 0: full size)"},
        {"fast.align_motion",
         &O::align_motion,
         0,
         0,
         "... on a moving camera, what it corrects of each frame's map: a shift, an affine map or "
         "a homography",
         {"shift", "affine", "homography"}},
        {"fast.align_max_px", &O::align_max_px, 0, 1e5,
         "... refused where it moves a moving camera's frame corner this far (px)"},
        {"fast.window_share", &O::window_share, 0, 1e9,
         "a crop step composes and samples only each frame's box of an atlas where the boxes "
         "together cover under this share of it (0: the whole atlas always)"},
        {"fast.restore_only", &O::restore_only, 0, 1,
         "the set-up fuses no atlas: a checkpoint replaces them (export and the studio set it on "
         "a fitted project)"},
        {"fast.static_align", &O::static_align, 0, 1,
         "a static camera's frames are aligned for hand shake"},
        {"fast.deblur_path", &O::deblur_path, 0, 1,
         "a layer never seen in focus trains through a deblurring filter"},
        {"fast.deblur_eps", &O::deblur_eps, 1e-9, 1,
         "... whose gain is capped at about 1/sqrt(eps)"},
        {"fast.deblur_lr", &O::deblur_lr, 0, 100, "... at this learning rate, times lr_atlas"},
        {"fast.deblur_min_radius", &O::deblur_min_radius, 0, 100,
         "... on layers blurred at least this much (px)"},
        {"fast.deblur_tv", &O::deblur_tv, 0, 100,
         "TV factor on an atlas with the path (estimated radius)"},
        {"fast.deblur_tv_given", &O::deblur_tv_given, 0, 100,
         "TV factor on an atlas with the path (radius given by --coc)"},
        {"fast.deblur_batch", &O::deblur_batch, 1, 64,
         "frames a step when a layer has the path and --batch is not given"},
        {"fast.pad",
         &O::pad,
         0,
         48,
         "px of scene the atlases hold beyond the frame",
         {},
         "the widest blur support"},
    };
    return f;
}

const std::vector<Field<PaperModelOptions>>& paper_fields() {
    using O = PaperModelOptions;
    static const std::vector<Field<O>> f = {
        {"paper.w_reco", &O::w_reco, 0, 1e6, "reconstruction weight (paper eq. 4, lambda1)"},
        {"paper.w_flow", &O::w_flow, 0, 1e6, "optical-flow consistency weight (lambda2)"},
        {"paper.w_sparsity", &O::w_sparsity, 0, 1e6, "alpha sparsity weight (lambda3)"},
        {"paper.w_rigid", &O::w_rigid, 0, 1e6, "mapping rigidity weight (lambda4)"},
        {"paper.w_bootstrap", &O::w_bootstrap, 0, 1e6, "alpha to the masks at the start"},
        {"paper.sparsity_start", &O::sparsity_start, 0, 1e9, "step where sparsity starts"},
        {"paper.sparsity_ramp", &O::sparsity_ramp, 0, 1e9, "steps over which sparsity ramps in"},
        {"paper.lr_map", &O::lr_map, 0, 10, "mapping MLPs' learning rate"},
        {"paper.lr_alpha", &O::lr_alpha, 0, 10, "alpha MLP's learning rate"},
        {"paper.lr_decoder", &O::lr_decoder, 0, 10, "atlas decoder's learning rate"},
        {"paper.lr_pretrain_atlas", &O::lr_pretrain_atlas, 0, 10,
         "atlas decoder's pre-training learning rate"},
        {"paper.pretrain_map_steps", &O::pretrain_map_steps, 0, 1e6, "mapping pre-training steps"},
        {"paper.pretrain_atlas_steps", &O::pretrain_atlas_steps, 0, 1e6,
         "atlas pre-training steps"},
        {"paper.mlp_stride", &O::mlp_stride, 1, 64,
         "MLPs evaluated every this many px, then interpolated"},
        {"paper.residual_px", &O::residual_px, 0, 1e4,
         "largest offset the mappings add to the geometric one (px)"},
    };
    return f;
}

const std::vector<Field<PerframeOptions>>& perframe_fields() {
    using O = PerframeOptions;
    static const std::vector<Field<O>> f = {
        {"perframe.lambda", &O::lambda, 0, 10, "TV weight of the per-frame MAP deconvolution"},
        {"perframe.iterations", &O::iterations, 1, 1e5, "ADMM iterations per frame"},
    };
    return f;
}

const std::vector<Field<StackCocOptions>>& radius_fields() {
    using O = StackCocOptions;
    static const std::vector<Field<O>> f = {
        {"radius.direct_blur", &O::direct_blur, 0, 1,
         "the reference path: blur at each radius directly, not by FFT (slow at large radii)"},
        {"radius.subject_boxes", &O::subject_boxes, 0, 1,
         "the subject's radius over a box around it in each frame (0: the whole frames)"},
        {"radius.absolute", &O::absolute, 0, 1,
         "add the composite's own blur, measured at its edges, to the stack's relative radius"},
        {"radius.floor_max", &O::floor_max, 0, 100,
         "the edges' floor counts up to this (px); past it, none"},
        {"radius.floor_lo", &O::floor_lo, 0, 100, "a floor under this reads 0 ..."},
        {"radius.floor_hi", &O::floor_hi, 0, 100, "... ramping up to the floor itself here (px)"},
        {"radius.fill_cells", &O::floor_fill_cells, 0, 1000,
         "empty floor cells take their neighbours' up to this far"},
        {"radius.gate_clear_px", &O::floor_gate_clear_px, 0, 1000,
         "the floor's gate reads views this far inside the layer's region (px)"},
        {"radius.spectral", &O::spectral, 0, 1,
         "a layer blurred past what edges measure is read from tile spectra"},
        {"radius.floor_frames", &O::floor_frames, 1, 1e6,
         "frames whose edges and tiles the floor reads, spread over the clip"},
        {"radius.floor_edges", &O::floor_edges, 0, 1e9,
         "edges the floor tests over those frames in all (0: up to 40000 a frame)"},
    };
    return f;
}

template <class T>
std::string number_text(T v) {
    if constexpr (std::is_same_v<T, bool>) {
        return v ? "true" : "false";
    } else if constexpr (std::is_integral_v<T>) {
        return std::to_string(v);
    } else {
        char b[40];
        std::snprintf(b, sizeof b, "%.10g", double(v));
        return b;
    }
}

template <class T>
std::string number_text_or_string(const T& v) {
    if constexpr (std::is_same_v<T, std::string>)
        return v;
    else
        return number_text(v);
}

[[noreturn]] std::string throw_bad(const std::string& msg) {
    throw Error(msg);
}

template <class S>
SettingInfo info_of(const Field<S>& f) {
    static const S defaults{};
    SettingInfo i;
    i.name = f.name;
    i.help = f.help;
    std::visit(
        [&](auto m) {
            using T = std::decay_t<decltype(defaults.*m)>;
            i.def = f.def_text ? f.def_text : number_text_or_string(defaults.*m);
            if constexpr (std::is_same_v<T, std::string>) {
                std::string c;
                for (const auto& s : f.choices) c += (c.empty() ? "" : "|") + s;
                i.type = "one of " + c;
                i.range = c;
            } else if constexpr (std::is_same_v<T, bool>) {
                i.type = "bool";
                i.range = "true|false";
            } else {
                i.type = std::is_integral_v<T> ? "integer" : "number";
                i.range = "[" + number_text(f.lo) + ", " + number_text(f.hi) + "]";
            }
        },
        f.member);
    return i;
}

// Parses `text` for the field's type and range; returns the canonical text.
template <class S>
std::string canonical(const Field<S>& f, const std::string& text) {
    const std::string head = "setting " + std::string(f.name) + ": ";
    return std::visit(
        [&](auto m) -> std::string {
            using T = std::decay_t<decltype(std::declval<S>().*m)>;
            if constexpr (std::is_same_v<T, std::string>) {
                for (const auto& c : f.choices)
                    if (c == text) return text;
                return throw_bad(head + "'" + text + "' is not one of " + info_of(f).range);
            } else if constexpr (std::is_same_v<T, bool>) {
                if (text == "1" || text == "true" || text == "on" || text == "yes") return "true";
                if (text == "0" || text == "false" || text == "off" || text == "no") return "false";
                return throw_bad(head + "'" + text + "' is not a bool (true|false)");
            } else {
                char* end = nullptr;
                const double v = std::strtod(text.c_str(), &end);
                if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v))
                    return throw_bad(head + "'" + text + "' is not a finite number");
                if (std::is_integral_v<T> && v != std::floor(v))
                    return throw_bad(head + "'" + text + "' is not an integer");
                if (v < f.lo || v > f.hi)
                    return throw_bad(head + text + " is out of range " + info_of(f).range);
                return number_text(T(v));
            }
        },
        f.member);
}

template <class S>
void apply_fields(const Settings& s, const std::vector<Field<S>>& fields, S& o) {
    for (const auto& f : fields) {
        if (!s.has(f.name)) continue;
        const std::string& v = s.value(f.name);
        std::visit(
            [&](auto m) {
                using T = std::decay_t<decltype(o.*m)>;
                if constexpr (std::is_same_v<T, std::string>)
                    o.*m = v;
                else if constexpr (std::is_same_v<T, bool>)
                    o.*m = v == "true";
                else
                    o.*m = T(std::strtod(v.c_str(), nullptr));
            },
            f.member);
    }
}

// Visits every field table with `fn(table)`.
template <class Fn>
void for_each_table(Fn&& fn) {
    fn(fit_fields());
    fn(setup_fields());
    fn(fast_fields());
    fn(paper_fields());
    fn(perframe_fields());
    fn(radius_fields());
}

// The canonical value of `name`; throws listing the names when there is no such setting.
std::string validate(const std::string& name, const std::string& value) {
    std::string out;
    bool found = false;
    for_each_table([&](const auto& table) {
        for (const auto& f : table)
            if (!found && name == f.name) {
                out = canonical(f, value);
                found = true;
            }
    });
    if (!found) {
        std::string names;
        for (const auto& i : all_settings()) names += (names.empty() ? "" : ", ") + i.name;
        throw Error("unknown setting '" + name + "' (valid: " + names +
                    "; `refocus fit --list-settings` says what each does)");
    }
    return out;
}

}  // namespace

const std::vector<SettingInfo>& all_settings() {
    static const std::vector<SettingInfo> all = [] {
        std::vector<SettingInfo> v;
        for_each_table([&](const auto& table) {
            for (const auto& f : table) v.push_back(info_of(f));
        });
        return v;
    }();
    return all;
}

std::string settings_table() {
    std::ostringstream o;
    o << "Settings of `refocus fit` and `refocus bench fit` (--set name=value; stored in "
         "project.json's fit.settings):\n";
    for (const auto& i : all_settings()) {
        o << "  " << i.name << " = " << i.def << "   (" << i.type;
        if (i.type == "number" || i.type == "integer") o << " in " << i.range;
        o << ")\n      " << i.help << "\n";
    }
    return o.str();
}

void Settings::set(const std::string& name, const std::string& value) {
    m_values[name] = validate(name, value);
}

void Settings::set_assignment(const std::string& a) {
    const size_t eq = a.find('=');
    if (eq == std::string::npos || eq == 0) throw Error("--set takes name=value (got '" + a + "')");
    set(a.substr(0, eq), a.substr(eq + 1));
}

void Settings::set_json(const nlohmann::json& obj, const std::string& where) {
    if (obj.is_null()) return;
    if (!obj.is_object()) throw Error(where + ": 'settings' must be an object of name: value");
    for (const auto& [name, v] : obj.items()) {
        std::string text;
        if (v.is_string())
            text = v.get<std::string>();
        else if (v.is_boolean())
            text = v.get<bool>() ? "true" : "false";
        else if (v.is_number())
            text = v.dump();
        else
            throw Error(where + ": setting " + name + " must be a number, a bool or a string");
        try {
            set(name, text);
        } catch (const Error& e) {
            throw Error(where + ": " + e.what());
        }
    }
}

nlohmann::json Settings::to_json() const {
    nlohmann::json j = nlohmann::json::object();
    for (const auto& [name, v] : m_values) {
        if (v == "true" || v == "false") {
            j[name] = v == "true";
            continue;
        }
        char* end = nullptr;
        const double d = std::strtod(v.c_str(), &end);
        if (!v.empty() && end == v.c_str() + v.size())
            j[name] = d;
        else
            j[name] = v;
    }
    return j;
}

std::string Settings::key(const std::string& prefix) const {
    std::string k;
    for (const auto& [name, v] : m_values)
        if (name.compare(0, prefix.size(), prefix) == 0) k += "/" + name + "=" + v;
    return k;
}

void apply_settings(const Settings& s, FitOptions& o) {
    apply_fields(s, fit_fields(), o);
}
void apply_settings(const Settings& s, FitSetupOptions& o) {
    apply_fields(s, setup_fields(), o);
}
void apply_settings(const Settings& s, FastModelOptions& o) {
    apply_fields(s, fast_fields(), o);
}
void apply_settings(const Settings& s, PaperModelOptions& o) {
    apply_fields(s, paper_fields(), o);
}
void apply_settings(const Settings& s, PerframeOptions& o) {
    apply_fields(s, perframe_fields(), o);
}
void apply_settings(const Settings& s, StackCocOptions& o) {
    apply_fields(s, radius_fields(), o);
}

}  // namespace refocus
