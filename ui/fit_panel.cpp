#include "fit_panel.h"

#include <imgui.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>

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

// The settings, Fit from scratch (asking before it discards a fit), Continue fitting.
void draw_fit_controls(FitPanelState& s, StudioContext& ctx, const FitWorker::Status& st) {
    const auto names = studio_preset_names();
    std::vector<const char*> items;
    for (const auto& n : names) items.push_back(n.c_str());
    ImGui::Combo("preset", &s.preset, items.data(), static_cast<int>(items.size()));
    ImGui::Checkbox("budget in steps", &s.use_iters);
    if (s.use_iters)
        ImGui::InputInt("steps", &s.budget_iters, 10, 100);
    else
        ImGui::SliderFloat("minutes", &s.budget_minutes, 0.5f, 60.0f, "%.1f min");
    ImGui::InputInt("seed", &s.seed);
    ImGui::InputText("radius maps (--coc)", s.coc_path, sizeof s.coc_path);
    ImGui::InputText("masks (--mask)", s.mask_path, sizeof s.mask_path);
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
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    ImGui::SameLine();
    ImGui::BeginDisabled(!ctx.worker->has_checkpoint());
    if (ImGui::Button("Continue fitting")) ctx.guarded([&] { start_fit(s, ctx, true); });
    ImGui::EndDisabled();
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
    ImGui::PlotLines("##psnr", psnr.data(), static_cast<int>(psnr.size()), 0, o2, FLT_MAX, FLT_MAX,
                     ImVec2(w, 80));
}

}  // namespace

void load_fit_panel(FitPanelState& p, const Project& project) {
    const FitSettings s = read_fit_settings(project);
    if (studio_preset_index(s.fit.preset) >= 0) p.preset = studio_preset_index(s.fit.preset);
    if (s.fit.iters > 0 && s.fit.minutes <= 0) {
        p.use_iters = true;
        p.budget_iters = static_cast<int>(s.fit.iters);
    } else if (s.fit.minutes > 0) {
        p.budget_minutes = static_cast<float>(s.fit.minutes);
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
        ImGui::SameLine();
        if (ImGui::Button("Stop")) ctx.worker->stop();
    }
    ImGui::Separator();
    const FitSnapshot& s = st.snap;
    ImGui::Text("state: %s%s", state_name(st.state),
                st.busy ? ("  (" + st.busy_what + ")").c_str() : "");
    char overlay[96];
    std::snprintf(overlay, sizeof overlay, "%.0f%%  elapsed %s  ETA %s", 100 * s.progress,
                  clock_text(s.elapsed_s).c_str(), clock_text(s.eta_s).c_str());
    ImGui::ProgressBar(static_cast<float>(s.progress), ImVec2(-1, 0), overlay);
    ImGui::Text("step %lld   reblur PSNR %.2f dB   loss %.5f", static_cast<long long>(s.step),
                s.reblur_psnr, s.loss);
    for (const auto& [k, v] : s.terms) ImGui::BulletText("%s  %.5g", k.c_str(), v);
    if (st.history.size() >= 2) draw_fit_curves(st);
    if (!st.error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", st.error.c_str());
}

}  // namespace refocus
