// The output rules of a fitted clip (docs/method.md, Confidence and fallback): where the sharp
// plate keeps the fit and where it keeps the shot. FitEngine's own methods; the fit itself is
// in fit_engine.cpp.
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>

#include "fit/confidence.h"
#include "fit/fit_engine.h"
#include "util/timing.h"
#include "fit/losses.h"
#include "ops/morphology.h"

namespace refocus {

namespace {
// The subject's radius in frame t: the median of its own map over its mask (on a grid of at
// most ~65 000 px, as focus_span reads it); NaN where the mask covers under 1 % of the frame.
// The output rules read the subject as a whole: a subject is at one depth, and its per-pixel
// estimate spreads by pixels where its median does not.
double subject_radius(const FitData& d, int t) {
    torch::NoGradGuard g;
    const int64_t step =
        std::max<int64_t>(1, int64_t(std::sqrt(double(d.height * d.width) / 65536.0)));
    auto grid = [&](const torch::Tensor& x) {
        return x.slice(-2, 0, d.height, step).slice(-1, 0, d.width, step);
    };
    auto r = grid(d.radius_fg[t]).to(torch::kFloat32).reshape({-1});
    auto in = grid(d.mask[t][0]).to(torch::kFloat32).reshape({-1}) >= 0.5;
    if (in.sum().item<int64_t>() < std::max<int64_t>(1, r.numel() / 100))
        return std::numeric_limits<double>::quiet_NaN();
    return r.masked_select(in).median().item<double>();
}

// Where frame t shows the subject, for the output rules: its mask where the radius there is
// the subject's (within a quarter of subject_radius or 1 px, smoothstep to twice that). An
// automatic mask that caught a piece of the wall (a blob beside the subject, a corner of the
// floor) reads the wall's radius there, and the rules treat it as wall. Undefined with one
// layer; `radius` (if given) receives subject_radius.
torch::Tensor subject_share(const FitData& d, int t, double* radius = nullptr) {
    if (!d.radius_fg.defined() || !d.radius_bg.defined() || !d.mask.defined()) return {};
    torch::NoGradGuard g;
    auto a = d.mask[t].view({1, 1, d.height, d.width}).to(torch::kFloat32);
    const double own = subject_radius(d, t);
    if (radius) *radius = own;
    if (!std::isfinite(own)) return a;
    const double tol = std::max(1.0, 0.25 * own);
    auto r = d.radius[t].view({1, 1, d.height, d.width}).to(torch::kFloat32);
    auto off = (((r - own).abs() - tol) / tol).clamp(0, 1);
    return a * (1.0 - off * off * (3 - 2 * off));
}

// ν and γ's reach of frame t's blur (confidence.h, blur_reach). With two layers the subject is
// in front (paper eq. 3, layered): its blur spills over the wall, the wall's never over it, so
// where frame t shows the subject (subject_share) the reach is the subject's own radius. A
// sharp subject in front of a blurred wall is the shot's best view of itself, not blur to fix.
torch::Tensor layered_reach(const FitData& d, int t) {
    double own = 0;
    auto a = subject_share(d, t, &own);
    if (!a.defined()) return blur_reach(d.radius[t]);
    torch::NoGradGuard g;
    if (!std::isfinite(own)) own = 0;
    auto fg = blur_reach(own * (a > 0.5).to(torch::kFloat32));
    auto bg = blur_reach(d.radius_bg[t]);
    return a * fg + (1.0 - a) * torch::maximum(bg, fg);
}

}  // namespace

torch::Tensor FitEngine::fallback_weight(int t) const {
    {
        std::lock_guard<std::mutex> lock(m_rule_memo_mutex);
        const RuleMemo& m = m_rule_memo;
        if (m.frame == t && m.step == m_step && m.has_fallback) return m.fallback;
    }
    auto f = fallback_weight_now(t);
    std::lock_guard<std::mutex> lock(m_rule_memo_mutex);
    if (m_rule_memo.frame != t || m_rule_memo.step != m_step) m_rule_memo = RuleMemo{t, m_step};
    m_rule_memo.fallback = f;
    m_rule_memo.has_fallback = true;
    return f;
}

torch::Tensor FitEngine::fallback_weight_now(int t) const {
    if (m_model->steps_itself() || !(m_opts.fallback_k > 0) || t < 0 || t >= m_data->frames)
        return {};
    // A fit that explains the clip leaves its own residual everywhere (resampling, the lens's
    // small differences): κ flags what passes fit.trusted_residual times that, over the noise
    // (which the evidence rule adds itself). Read before the lock: residual_rms takes it.
    double floor = m_opts.fallback_floor;
    if (m_opts.trusted_residual > 0 && m_opts.fallback_change > 0) {
        const double m = model_trust();
        if (m > 0)
            floor =
                std::max(floor, m * m_opts.trusted_residual *
                                    residual_excess(residual_rms(), m_data->noise_levels) / 255.0);
    }
    std::lock_guard<std::mutex> lock(m_unexplained_mutex);
    if (m_unexplained_step != m_step) {
        m_unexplained.assign(m_data->frames, torch::Tensor());
        m_unexplained_step = m_step;
    }
    auto f = temporal_unexplained(
        t, m_data->frames, m_opts.fallback_frames, m_data->to_ref, m_data->static_camera,
        [&](int s) {
            auto& u = m_unexplained[s];
            if (u.defined()) return u;  // an unmeasured frame stays undefined and is asked again
            auto resid = residual_frame(s);
            if (!resid.defined()) return u;
            resid = resid.unsqueeze(0);
            if (!(m_opts.fallback_change > 0))
                u = unexplained_share(resid, m_opts.fallback_k, m_opts.fallback_min);
            else if (!(resid < 0).any().item<bool>())
                u = unexplained_share_evidence(resid, model_change(s),
                                               std::max(m_data->noise_levels, 0.0),
                                               m_opts.fallback_change, floor);
            return u;
        });
    // Only the window around the frame asked for is kept: an export goes in order, and a 1080p
    // clip's 240 shares would hold 2 GB.
    const int keep = std::max(m_opts.fallback_frames, 0) + 1;
    for (int s = 0; s < int(m_unexplained.size()); ++s)
        if (std::abs(s - t) > keep) m_unexplained[s] = torch::Tensor();
    if (!f.defined() || !(f > 1e-3).any().item<bool>()) return {};
    return f;
}

torch::Tensor FitEngine::sharpest_seen_map(int t) const {
    if (m_model->steps_itself() || t < 0 || t >= m_data->frames) return {};
    std::lock_guard<std::mutex> lock(m_unexplained_mutex);
    if (m_seen.empty()) {
        m_seen.assign(m_data->frames, torch::Tensor());
        m_seen_range.assign(m_data->frames, torch::Tensor());
    }
    // A static camera sees each pixel at the same place in every frame: one map, over all of
    // them, serves every frame.
    const bool still = m_data->static_camera;
    const int i = still ? 0 : t;
    // A moving camera's maps are per frame: the neighbours' are kept (export and playback go in
    // order), not every frame's (at 1080p × 240, 4 GB).
    if (!still)
        for (int s = 0; s < int(m_seen.size()); ++s)
            if (std::abs(s - t) > 2) m_seen[s] = m_seen_range[s] = torch::Tensor();
    // With two layers each layer is read on its own radius (split_radius_by_layer): a subject
    // crossing the wall changes the visible surface's radius, not the focus on the wall, and a
    // sharp subject passing in front of a blurred wall is no sharp view of the wall.
    const bool layered =
        m_data->radius_fg.defined() && m_data->radius_bg.defined() && m_data->mask.defined();
    const bool range = m_opts.focus_moved_px > 0;
    auto& best = m_seen[i];
    if (!best.defined()) {
        // Where a frame did not see the pixel it reads past any trust: it lowers no minimum.
        const double unseen = 4.0 * std::max(m_opts.trust_seen_px, 2.0) + 1.0;
        auto seen = [&](const torch::Tensor& maps, bool most) {
            return seen_radius(
                i, m_data->frames, still ? m_data->frames : 32, m_data->to_ref, still, unseen,
                [&](int s) { return maps[s]; }, most);
        };
        if (layered) {
            auto bg = seen(m_data->radius_bg, range);
            best = bg.least;
            if (range) m_seen_range[i] = bg.most - bg.least;  // the subject's: focus_range_map
        } else {
            auto visible = seen(m_data->radius, range);
            best = visible.least;
            if (range) m_seen_range[i] = visible.most - visible.least;
        }
        if (m_spans.empty()) m_spans = layer_spans(layered);
    }
    if (!layered || m_spans.size() != 2 || !m_spans[0].seen) return best;
    // The subject moves with its own track, not the camera's: its sharpest view is a frame's.
    torch::NoGradGuard g;
    auto a = subject_share(*m_data, t);
    return a * m_spans[0].least + (1.0 - a) * best;
}

torch::Tensor FitEngine::model_change(int t) const {
    // Under m_unexplained_mutex (fallback_weight's). A viewer asks for a frame at every step of
    // a fit, and each asks for its neighbours': a recent map spares their renders.
    constexpr int64_t kChangeSteps = 50;
    for (const auto& c : m_change)
        if (c.frame == t && std::abs(c.step - m_step) <= kChangeSteps) return c.map;
    torch::NoGradGuard g;
    const Layers L = rendered_layers(t);  // the export's render of the frame serves both
    // A damaged model has no change to measure; the export's own check names it.
    if (!torch::isfinite(L.sharp).all().item<bool>()) return {};
    auto d = (srgb_encode(L.sharp) - srgb_encode(reblur(L, {t}))).abs().mean(1, true);
    d = box_filter(d, 2);
    // Keeps the frames of one fallback window and the next frame's (an export goes in order).
    const size_t keep = size_t(2 * std::max(m_opts.fallback_frames, 0) + 2);
    while (m_change.size() >= keep) m_change.pop_front();
    m_change.push_back({t, m_step, d});
    return d;
}

double FitEngine::residual_rms() const {
    if (!m_resid.defined()) return std::numeric_limits<double>::quiet_NaN();
    std::lock_guard<std::mutex> lock(m_unexplained_mutex);
    if (m_resid_rms_step == m_step && m_resid_rms_step >= 0) return m_resid_rms;
    torch::NoGradGuard g;
    const int T = m_data->frames, n = std::min(T, 32);
    double sum = 0;
    int counted = 0;
    for (int k = 0; k < n; ++k) {
        const int s = n > 1 ? int(std::lround(double(k) * (T - 1) / (n - 1))) : 0;
        const auto r = residual_frame(s);
        const int64_t H = r.size(1), W = r.size(2);
        const int64_t step = std::max<int64_t>(1, int64_t(std::sqrt(double(H * W) / 65536.0)));
        auto v = r.slice(1, 0, H, step).slice(2, 0, W, step).flatten();
        auto seen = v.masked_select(v >= 0).to(torch::kFloat64);
        if (seen.numel() == 0) continue;  // a frame no step has reached yet
        sum += seen.pow(2).mean().sqrt().item<double>() * 255.0;
        ++counted;
    }
    m_resid_rms = counted > 0 ? sum / counted : std::numeric_limits<double>::quiet_NaN();
    m_resid_rms_step = m_step;
    return m_resid_rms;
}

double FitEngine::model_trust() const {
    if (!(m_opts.explained_rms > 0)) return 0.0;
    return explained_trust(residual_rms(), m_data->noise_levels, m_opts.explained_rms);
}

double FitEngine::reported_trust() const {
    return m_opts.explained_rms > 0 ? model_trust() : std::numeric_limits<double>::quiet_NaN();
}

torch::Tensor FitEngine::focus_range_map(int t) const {
    if (!(m_opts.focus_moved_px > 0) || !sharpest_seen_map(t).defined()) return {};
    torch::Tensor r;
    {
        std::lock_guard<std::mutex> lock(m_unexplained_mutex);
        r = m_seen_range[m_data->static_camera ? 0 : t];
    }
    const double moved = m_opts.focus_moved_px, travel = m_opts.focus_travel_px;
    auto travel_of = [&](size_t k) {
        return k < m_spans.size() && m_spans[k].seen ? m_spans[k].most - m_spans[k].least : 0.0;
    };
    auto a = subject_share(*m_data, t);
    if (!a.defined() || m_spans.size() != 2)  // one layer: the visible surface's
        return range_by_travel(r, travel_of(0), moved, travel);
    // Two layers: each layer's range where frame t shows it. The subject moves with its own
    // track, not the camera's: how far its focus moved is its travel (the range of its
    // per-frame medians), not the range of whatever crossed its pixels.
    torch::NoGradGuard g;
    return a * range_by_travel(torch::full_like(r, travel_of(0)), travel_of(0), moved, travel) +
           (1.0 - a) * range_by_travel(r, travel_of(1), moved, travel);
}

std::vector<FocusSpan> FitEngine::layer_spans(bool layered) const {
    const int T = m_data->frames;
    if (!layered)
        return {focus_span(
            T, [&](int s) { return m_data->radius[s]; }, nullptr)};
    auto mask = [&](int s) { return m_data->mask[s][0]; };  // focus_span reads it on its grid
    auto unmasked = [&](int s) { return 1.0 - m_data->mask[s][0].to(torch::kFloat32); };
    return {focus_span(
                T, [&](int s) { return m_data->radius_fg[s]; }, mask),
            focus_span(
                T, [&](int s) { return m_data->radius_bg[s]; }, unmasked)};
}

torch::Tensor FitEngine::seen_trust_map(int t) const {
    if (!(m_opts.trust_seen_px > 0)) return {};
    auto best = sharpest_seen_map(t);
    return best.defined() ? seen_trust(best, m_opts.trust_seen_px) : best;
}

torch::Tensor FitEngine::confidence(int t) const {
    auto f = fallback_weight(t);
    auto k = f.defined() ? 1.0 - f : torch::ones({1, 1, m_data->height, m_data->width});
    auto tau = seen_trust_map(t);
    return tau.defined() ? k * tau : k;
}

torch::Tensor FitEngine::model_weight(int t, torch::Tensor* gamma) const {
    {
        std::lock_guard<std::mutex> lock(m_rule_memo_mutex);
        const RuleMemo& m = m_rule_memo;
        if (m.frame == t && m.step == m_step && m.has_weight) {
            if (gamma) *gamma = m.gamma;
            return m.weight;
        }
    }
    torch::Tensor g;
    auto w = model_weight_now(t, &g);
    if (gamma) *gamma = g;
    std::lock_guard<std::mutex> lock(m_rule_memo_mutex);
    if (m_rule_memo.frame != t || m_rule_memo.step != m_step) m_rule_memo = RuleMemo{t, m_step};
    m_rule_memo.weight = w;
    m_rule_memo.gamma = g;
    m_rule_memo.has_weight = true;
    return w;
}

torch::Tensor FitEngine::model_weight_now(int t, torch::Tensor* gamma) const {
    if (gamma) *gamma = torch::Tensor();
    if (t < 0 || t >= m_data->frames) return {};
    StageClock clock;  // --debug timing
    clock.next("rules: κ and τ (confidence)");
    auto w = confidence(t);
    clock.next("rules: the sharpest view");
    auto best = m_opts.sharper_view_px > 0 ? sharpest_seen_map(t) : torch::Tensor();
    if (m_opts.keep_focus_px > 0 || best.defined()) {
        clock.next("rules: γ and ν");
        const auto reach = layered_reach(*m_data, t);  // ν and γ share the dilation
        if (m_opts.keep_focus_px > 0) w = w * blur_need(reach, m_opts.keep_focus_px);
        if (best.defined()) {
            auto g = sharper_view(reach, best, focus_range_map(t), m_opts.sharper_view_px,
                                  m_opts.sharper_view_moved_px, m_opts.focus_moved_px);
            // With fit.trusted_blur_px, a fit that explains the clip restores where frame t is
            // its own sharpest view too, where the blur reaches twice that: under it the shot's
            // own detail beats the resampled atlas. Off by default: the residual cannot see a
            // radius or lens that is wrong in the blur's null space (docs/method.md).
            const double m = m_opts.trusted_blur_px > 0 ? model_trust() : 0.0;
            if (m > 0) g = torch::maximum(g, m * blur_need(reach, m_opts.trusted_blur_px));
            w = w * g;
            if (gamma) *gamma = g;
        }
    }
    if (!(w < 1 - 1e-3).any().item<bool>()) return {};
    return w;
}

void FitEngine::apply_fallback(Layers& L, int t, const Layers* model) const {
    if (!L.sharp.defined() || t < 0 || t >= m_data->frames) return;
    auto w = model_weight(t);
    const bool lock = m_opts.lock_low_px > 0;
    if (!w.defined() && !lock) return;
    torch::NoGradGuard g;
    auto in = m_data->input[t].unsqueeze(0);
    // The lock's correction, from the model's plate, is added to every layer so that
    // α·F + (1 − α)·B takes it as the plate does.
    torch::Tensor lift;
    StageClock clock;  // --debug timing
    clock.next("rules: the low band's lock");
    if (lock) {
        // The input's low band is the sharp frame's only where the blur is far under the lock's
        // scale; elsewhere it is the reblur's. A fit that explains the clip says what the blur
        // changed there (its reblur); one that does not is held to the input's low band.
        const Layers& M = model && model->sharp.defined() ? *model : L;
        const double m = model_trust();
        auto ref = m > 0 ? m * reblur(M, {t}) + (1.0 - m) * M.sharp : M.sharp;
        lift = low_frequency_lock(ref, in, m_opts.lock_low_px);
    }
    // The layers blend as the plate does, so that α·F + (1 − α)·B stays the plate (the
    // refocused frames are made from the layers); edits (x − the model's x) stay on top.
    auto blend = [&](torch::Tensor& x, const torch::Tensor& x_model) {
        if (!x.defined()) return;
        const torch::Tensor& base = x_model.defined() ? x_model : x;
        auto fixed = lift.defined() ? base + lift : base;
        x = (w.defined() ? w * fixed + (1.0 - w) * in : fixed) + (x - base);
    };
    clock.next("rules: the blend");
    blend(L.sharp, model ? model->sharp : torch::Tensor());
    blend(L.bg, model ? model->bg : torch::Tensor());
    blend(L.fg, model ? model->fg : torch::Tensor());
}

}  // namespace refocus
