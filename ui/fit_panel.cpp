#include "fit_panel.h"

#include <imgui.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>

#include "item_tip.h"
#include "prepare/noise.h"
#include "session/fit_session.h"
#include "studio_context.h"
#include "studio_presets.h"
#include "util/error.h"

namespace refocus {

namespace {

std::string clock_text(double s) {
    if (s < 0) return "--:--";
    char b[32];
    std::snprintf(b, sizeof b, "%d:%02d", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
    return b;
}

// The preset combo, each preset's line as its tooltip.
void draw_preset_combo(FitPanelState& s) {
    const auto& presets = fit_presets();
    s.preset = std::clamp(s.preset, 0, static_cast<int>(presets.size()) - 1);
    if (ImGui::BeginCombo("preset", presets[s.preset].name.c_str())) {
        for (int i = 0; i < static_cast<int>(presets.size()); ++i) {
            if (ImGui::Selectable(presets[i].name.c_str(), i == s.preset)) s.preset = i;
            item_tip(presets[i].description.c_str());
        }
        ImGui::EndCombo();
    }
    item_tip(("The fit's model. " + presets[s.preset].name + ": " + presets[s.preset].description)
                 .c_str());
}

// The settings, Fit from scratch (asking before it discards a fit), Continue fitting.
void draw_fit_controls(FitPanelState& s, StudioContext& ctx, const FitWorker::Status& st) {
    draw_preset_combo(s);
    ImGui::Checkbox("budget in steps", &s.use_iters);
    item_tip(
        "Budget the fit in optimisation steps instead of minutes (steps give the same result "
        "on any machine; minutes fit the time you have).");
    if (s.use_iters) {
        ImGui::InputInt("steps", &s.budget_iters, 10, 100);
        item_tip(
            "Optimisation steps this run adds (Continue fitting adds them to the "
            "checkpoint's).");
    } else {
        ImGui::SliderFloat("minutes", &s.budget_minutes, 0.5f, 60.0f, "%.1f min");
        item_tip(
            "Wall-clock minutes for this run, the preparation (flow, masks, radius) "
            "included; Continue fitting adds exactly these minutes. Ctrl+click to type.");
    }
    ImGui::InputInt("seed", &s.seed);
    item_tip(
        "Random seed of the fit (initialisation and frame order): the same seed and "
        "budget in steps give the same fit.");
    ImGui::InputText("radius maps (--coc)", s.coc_path, sizeof s.coc_path);
    item_tip(
        "Optional: per-frame circle-of-confusion maps (EXR, px), a printf pattern such as "
        "coc/coc_%04d.exr, used instead of the radius estimated from the clip.");
    ImGui::InputText("masks (--mask)", s.mask_path, sizeof s.mask_path);
    item_tip(
        "Optional: a roto matte of the moving subject (a printf pattern of images, white on "
        "the subject) instead of the automatic masks; it separates a foreground layer.");
    if (ImGui::Button("Fit from scratch")) {
        if (ctx.worker->has_checkpoint())
            ImGui::OpenPopup("Discard the fit?");
        else
            ctx.guarded([&] { start_fit(s, ctx, false); });
    }
    if (ImGui::BeginPopupModal("Discard the fit?", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::Text(
            "The project is fitted (step %lld). Start over from nothing?\n"
            "(Continue fitting keeps the work and adds the budget.)",
            static_cast<long long>(st.snap.step));
        if (ImGui::Button("Start over")) {
            ImGui::CloseCurrentPopup();
            ctx.guarded([&] { start_fit(s, ctx, false); });
        }
        item_tip("Replace the fitted layers with a new fit (the atlas paint is kept).");
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
        item_tip("Keep the fit as it is.");
        ImGui::EndPopup();
    }
    item_tip("Start a new fit with these settings (asks before it replaces the fitted one).");
    ImGui::SameLine();
    ImGui::BeginDisabled(!ctx.worker->has_checkpoint());
    if (ImGui::Button("Continue fitting")) ctx.guarded([&] { start_fit(s, ctx, true); });
    ImGui::EndDisabled();
    item_tip("Go on from the checkpoint for the budget above (added to the fit so far).");
}

// While preparing: the step, the elapsed time and an estimate; while fitting: the budget used.
void draw_fit_progress(const FitWorker::Status& st) {
    char overlay[160];
    if (st.state == FitWorker::State::Preparing) {
        const auto& p = st.prep;
        std::snprintf(overlay, sizeof overlay, "%.0f%%  %s  elapsed %s  ETA %s", 100 * p.progress,
                      p.stage.empty() ? "waiting" : p.stage.c_str(),
                      clock_text(p.elapsed_s).c_str(), clock_text(p.eta_s).c_str());
        ImGui::ProgressBar(static_cast<float>(p.progress), ImVec2(-1, 0), overlay);
        item_tip(
            "Preparing the clip (optical flow, camera motion, masks, radius maps), before "
            "the first step; the time counts in a budget in minutes. The estimate learns "
            "from the steps done so far.");
        return;
    }
    const FitSnapshot& s = st.snap;
    if (st.state == FitWorker::State::Fitting || st.state == FitWorker::State::Paused) {
        std::snprintf(overlay, sizeof overlay, "%.0f%%  elapsed %s  ETA %s", 100 * s.progress,
                      clock_text(s.elapsed_s).c_str(), clock_text(s.eta_s).c_str());
        ImGui::ProgressBar(static_cast<float>(s.progress), ImVec2(-1, 0), overlay);
        item_tip("The share of the fit's budget used, its training time and the time left.");
        if (st.prep_s > 0) ImGui::TextDisabled("prepared in %s", clock_text(st.prep_s).c_str());
    } else if (s.step > 0) {
        ImGui::Text("fitted: %lld steps, %s of training", static_cast<long long>(s.step),
                    clock_text(s.elapsed_s).c_str());
    }
}

// Loss and reblur PSNR over the steps. Per-batch values are noisy (each step sees other
// frames): an exponential moving average.
void draw_fit_curves(const FitWorker::Status& st) {
    std::vector<float> loss, psnr;
    loss.reserve(st.history.size());
    double l = std::log10(std::max(st.history[0].loss, 1e-9)), p = st.history[0].reblur_psnr;
    for (const auto& h : st.history) {
        l += 0.1 * (std::log10(std::max(h.loss, 1e-9)) - l);
        p += 0.1 * (h.reblur_psnr - p);
        loss.push_back(static_cast<float>(l));
        psnr.push_back(static_cast<float>(p));
    }
    char o1[48], o2[48];
    std::snprintf(o1, sizeof o1, "loss %.4g", st.history.back().loss);
    std::snprintf(o2, sizeof o2, "reblur %.2f dB", st.history.back().reblur_psnr);
    const float w = ImGui::GetContentRegionAvail().x;
    ImGui::TextUnformatted("loss (log scale) and reblur PSNR, smoothed, over the steps");
    ImGui::PlotLines("##loss", loss.data(), static_cast<int>(loss.size()), 0, o1, FLT_MAX, FLT_MAX,
                     ImVec2(w, 80));
    item_tip("The loss over the steps (log scale, smoothed): it falls as the fit converges.");
    ImGui::PlotLines("##psnr", psnr.data(), static_cast<int>(psnr.size()), 0, o2, FLT_MAX, FLT_MAX,
                     ImVec2(w, 80));
    item_tip("Reblur PSNR over the steps (smoothed): it rises as the fit converges.");
}

}  // namespace

void load_fit_panel(FitPanelState& p, const Project& project) {
    const FitSettings s = read_fit_settings(project);
    if (studio_preset_index(s.fit.preset) >= 0) p.preset = studio_preset_index(s.fit.preset);
    p.use_iters = s.fit.iters > 0 && s.fit.minutes <= 0;
    // A fitted project's budget is the checkpoint's running total (what the engine stops at),
    // not what was typed: the fields keep theirs, so that Continue adds what they show.
    if (!FitEngine::has_checkpoint(fit_dir(project))) {
        if (p.use_iters) p.budget_iters = static_cast<int>(s.fit.iters);
        if (!p.use_iters && s.fit.minutes > 0) p.budget_minutes = static_cast<float>(s.fit.minutes);
    }
    p.seed = static_cast<int>(s.fit.seed);
    std::snprintf(p.coc_path, sizeof p.coc_path, "%s", s.setup.coc_path.c_str());
    std::snprintf(p.mask_path, sizeof p.mask_path, "%s", s.setup.mask_path.c_str());
}

void start_fit(const FitPanelState& p, StudioContext& ctx, bool resume) {
    FitSettings s = ctx.worker->settings();
    s.fit.preset = studio_preset_names().at(p.preset);
    s.fit.minutes = p.use_iters ? 0.0 : p.budget_minutes;
    s.fit.iters = p.use_iters ? p.budget_iters : 0;
    if (s.fit.minutes <= 0 && s.fit.iters <= 0)
        throw Error("give the fit a budget: minutes or steps");
    s.fit.seed = static_cast<uint64_t>(std::max(0, p.seed));
    s.setup.coc_path = p.coc_path;
    s.setup.mask_path = p.mask_path;
    ctx.worker->start(s, resume);
    ctx.depth_requested = false;
}

void draw_fit_panel(FitPanelState& p, StudioContext& ctx) {
    if (!ctx.doc.is_open()) {
        ImGui::TextWrapped("Open or create a project first (File menu).");
        return;
    }
    const FitWorker::Status st = ctx.worker->status(true);
    const bool running =
        st.state == FitWorker::State::Fitting || st.state == FitWorker::State::Paused;
    ImGui::BeginDisabled(running || st.busy);
    draw_fit_controls(p, ctx, st);
    ImGui::EndDisabled();
    if (running) {
        const bool paused = st.state == FitWorker::State::Paused;
        if (ImGui::Button(paused ? "Resume" : "Pause")) ctx.worker->set_paused(!paused);
        item_tip(paused ? "Go on fitting."
                        : "Hold the fit after its current step (the studio "
                          "stays responsive; the time budget waits).");
        ImGui::SameLine();
        if (ImGui::Button("Stop")) ctx.worker->stop();
        item_tip(
            "End the fit after its current step and save a checkpoint (Continue fitting "
            "goes on from it).");
    }
    ImGui::Separator();
    // The clip's noise, as refocus new measured it (not measured again here: the UI thread).
    const Project& project = ctx.doc.project();
    if (project.sections.contains("noise")) {
        try {
            const NoiseEstimate n =
                NoiseEstimate::from_json(project.sections.at("noise"), "project.json");
            ImGui::Text("clip noise: sigma %.2f levels", n.mean());
            item_tip(("Measured when the clip was ingested: the standard deviation of its noise "
                      "in 8-bit levels, where the frames are flat (" +
                      n.describe() + "). After H.264 it is the noise the codec left.")
                         .c_str());
        } catch (const std::exception&) {
        }
    }
    const FitSnapshot& s = st.snap;
    ImGui::Text("state: %s%s", state_name(st.state),
                st.busy ? ("  (" + st.busy_what + ")").c_str() : "");
    draw_fit_progress(st);
    if (st.state != FitWorker::State::Preparing && s.step > 0) {
        ImGui::Text("step %lld   reblur PSNR %.2f dB   loss %.5f", static_cast<long long>(s.step),
                    s.reblur_psnr, s.loss);
        item_tip(
            "Reblur PSNR: how closely the fitted sharp layers, blurred again, match the "
            "clip (higher is better). Loss: what the fit minimises.");
        if (std::isfinite(s.residual_rms) && !std::isfinite(s.trust)) {
            ImGui::Text("residual %.2f levels RMS", s.residual_rms);
            item_tip(
                "How far the fit's reblur misses the clip (8-bit levels, the mean over frames of "
                "its RMS). Near the noise the fit explains the clip; with fit.explained_rms 0 "
                "the trust is off and the input's low band holds.");
        } else if (std::isfinite(s.residual_rms)) {
            ImGui::Text("residual %.2f levels RMS: %s", s.residual_rms,
                        s.trust >= 0.999   ? "the fit explains the clip"
                        : s.trust <= 0.001 ? "not trusted"
                                           : "partly trusted");
            item_tip(
                "How far the fit's reblur misses the clip (8-bit levels, the mean over frames of "
                "its RMS). Near the noise (fit.explained_rms) the fit explains the clip: the sharp "
                "output keeps the low band the model restores; above it, the input's low band "
                "holds. fit.trusted_blur_px lets a trusted fit deconvolve where no frame saw "
                "sharper.");
        }
        for (const auto& [k, v] : s.terms) ImGui::BulletText("%s  %.5g", k.c_str(), v);
    }
    if (st.history.size() >= 2) draw_fit_curves(st);
    if (!st.error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", st.error.c_str());
}

}  // namespace refocus
