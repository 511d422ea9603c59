// The side panel: Fit (preset, budget, start/pause/stop/resume, live loss and reblur PSNR,
// ETA), Focus (lens at the playhead, keyframes, click-to-focus, tracking), Export (passes,
// format, range, progress with cancel) and Log.
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

#include "studio_app.h"
#include "util/error.h"

namespace refocus {

namespace {
constexpr float kSideWidth = 380.0f;
const char* kPresets[] = {"fast", "paper", "perframe"};

std::string clock_text(double s) {
    if (s < 0) return "--:--";
    char b[32];
    std::snprintf(b, sizeof b, "%d:%02d", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
    return b;
}

// The export panel's passes, in its checkbox order.
struct PassInfo {
    const char* label;
    const char* name;  // export_pass name
};
const PassInfo kPasses[] = {{"sharp plate", "sharp"}, {"refocused video", "refocus"},
                            {"atlases (edited)", "atlas"}, {"alpha", "alpha"},
                            {"radius (CoC)", "coc"},       {"inverse depth", "depth"},
                            {"UV maps", "uv"},             {"reblur", "reblur"}};
const char* kFormats[] = {"png", "tiff", "exr", "mp4"};
}  // namespace

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

void Studio::start_fit(bool resume) {
    FitSettings s = m_worker->settings();
    s.fit.preset = kPresets[m_preset];
    s.fit.minutes = m_use_iters ? 0.0 : m_budget_minutes;
    s.fit.iters = m_use_iters ? m_budget_iters : 0;
    if (s.fit.minutes <= 0 && s.fit.iters <= 0) throw Error("give the fit a budget: minutes or steps");
    s.fit.seed = static_cast<uint64_t>(std::max(0, m_seed));
    s.setup.coc_path = m_coc_path;
    s.setup.mask_path = m_mask_path;
    m_worker->start(s, resume);
    m_depth_requested = false;
}

void Studio::set_key(const std::string& name, int frame, double value, Easing e) {
    for (const LaneInfo& l : focus_lanes())
        if (name == l.name || (name == "rim" && l.lane == &FocusTrack::beta) ||
            (name == "beta" && l.lane == &FocusTrack::beta) ||
            (name == "highlight_gain" && l.lane == &FocusTrack::highlight_gain) ||
            (name == "rotation_deg" && l.lane == &FocusTrack::rotation_deg)) {
            if (!std::isfinite(value)) throw Error("keyframe value for " + name + " is not a number");
            (m_doc.focus().*(l.lane)).set(frame, std::clamp(value, l.min, l.max), e);
            m_doc.mark_dirty();
            m_view_dirty = true;
            return;
        }
    throw Error("unknown focus lane '" + name + "'");
}

void Studio::focus_at_pixel(int frame, int x, int y) {
    if (!m_depth) throw Error("the depth is not ready yet: fit the project first (Fit tab)");
    if (!m_view || m_view->t != frame) throw Error("frame " + std::to_string(frame) + " is still rendering");
    const FrameMaps& m = m_view->maps;
    const float d = m_depth->depth_at_pixel(frame, x, y, m.uv_bg, m.uv_fg, m.alpha);
    set_key("focus", frame, d, m_new_key_easing);
    // Refocusing needs an aperture: the clip's own (1) when none is keyed yet.
    if (m_doc.focus().aperture.keys.empty()) set_key("aperture", frame, 1.0, m_new_key_easing);
    m_info = "focus key at frame " + std::to_string(frame);
}

void Studio::track_pixel(int frame, int x, int y) {
    if (!m_depth) throw Error("the depth is not ready yet: fit the project first (Fit tab)");
    if (!m_view || m_view->t != frame) throw Error("frame " + std::to_string(frame) + " is still rendering");
    const FrameMaps& m = m_view->maps;
    FocusTarget tgt;
    const bool fg = !m.alpha.empty() && m.alpha.at(x, y, 0) > 0.5f;
    const Image& uv = fg ? m.uv_fg : m.uv_bg;
    tgt.layer = fg ? DepthModel::Foreground : DepthModel::Background;
    tgt.u = uv.at(x, y, 0);
    tgt.v = uv.at(x, y, 1);
    tgt.from_frame = 0;
    tgt.to_frame = m_source->frames() - 1;
    m_doc.focus().track = tgt;
    if (m_doc.focus().aperture.keys.empty()) set_key("aperture", frame, 1.0, m_new_key_easing);
    m_doc.mark_dirty();
    m_view_dirty = true;
    m_info = std::string("tracking a point of the ") + (fg ? "foreground" : "background");
}

void Studio::draw_side_panel() {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    ImGui::SetNextWindowPos(ImVec2(vp->WorkPos.x + vp->WorkSize.x - kSideWidth, vp->WorkPos.y));
    ImGui::SetNextWindowSize(ImVec2(kSideWidth, vp->WorkSize.y));
    ImGui::Begin("Panel", nullptr,
                 ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                     ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoSavedSettings);
    if (!m_info.empty()) ImGui::TextDisabled("%s", m_info.c_str());
    if (ImGui::BeginTabBar("tabs")) {
        if (ImGui::BeginTabItem("Fit")) {
            draw_fit_tab();
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Focus")) {
            draw_focus_tab();
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Export")) {
            draw_export_tab();
            ImGui::EndTabItem();
        }
        if (ImGui::BeginTabItem("Log")) {
            draw_log_tab();
            ImGui::EndTabItem();
        }
        ImGui::EndTabBar();
    }
    ImGui::End();
}

void Studio::draw_fit_tab() {
    if (!m_doc.is_open()) {
        ImGui::TextWrapped("Open or create a project first (File menu).");
        return;
    }
    const FitWorker::Status st = m_worker->status(true);
    const bool running = st.state == FitWorker::State::Fitting || st.state == FitWorker::State::Paused;
    ImGui::BeginDisabled(running || st.busy);
    ImGui::Combo("preset", &m_preset, kPresets, 3);
    ImGui::Checkbox("budget in steps", &m_use_iters);
    if (m_use_iters) ImGui::InputInt("steps", &m_budget_iters, 10, 100);
    else ImGui::SliderFloat("minutes", &m_budget_minutes, 0.5f, 60.0f, "%.1f min");
    ImGui::InputInt("seed", &m_seed);
    ImGui::InputText("radius maps (--coc)", m_coc_path, sizeof m_coc_path);
    ImGui::InputText("masks (--mask)", m_mask_path, sizeof m_mask_path);
    if (ImGui::Button("Fit from scratch")) {
        if (m_worker->has_checkpoint()) ImGui::OpenPopup("Discard the fit?");
        else guarded([&] { start_fit(false); });
    }
    if (ImGui::BeginPopupModal("Discard the fit?", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
        ImGui::Text("The project is fitted (step %lld). Start over from nothing?\n"
                    "(Continue fitting keeps the work and adds the budget.)",
                    static_cast<long long>(st.snap.step));
        if (ImGui::Button("Start over")) {
            ImGui::CloseCurrentPopup();
            guarded([&] { start_fit(false); });
        }
        ImGui::SameLine();
        if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
        ImGui::EndPopup();
    }
    ImGui::SameLine();
    ImGui::BeginDisabled(!m_worker->has_checkpoint());
    if (ImGui::Button("Continue fitting")) guarded([&] { start_fit(true); });
    ImGui::EndDisabled();
    ImGui::EndDisabled();
    if (running) {
        const bool paused = st.state == FitWorker::State::Paused;
        if (ImGui::Button(paused ? "Resume" : "Pause")) m_worker->set_paused(!paused);
        ImGui::SameLine();
        if (ImGui::Button("Stop")) m_worker->stop();
    }
    ImGui::Separator();
    const FitSnapshot& s = st.snap;
    ImGui::Text("state: %s%s", state_name(st.state), st.busy ? ("  (" + st.busy_what + ")").c_str() : "");
    char overlay[96];
    std::snprintf(overlay, sizeof overlay, "%.0f%%  elapsed %s  ETA %s", 100 * s.progress,
                  clock_text(s.elapsed_s).c_str(), clock_text(s.eta_s).c_str());
    ImGui::ProgressBar(static_cast<float>(s.progress), ImVec2(-1, 0), overlay);
    ImGui::Text("step %lld   reblur PSNR %.2f dB   loss %.5f", static_cast<long long>(s.step),
                s.reblur_psnr, s.loss);
    for (const auto& [k, v] : s.terms) ImGui::BulletText("%s  %.5g", k.c_str(), v);
    if (st.history.size() >= 2) {
        // Per-batch values are noisy (each step sees other frames): exponential moving average.
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
    if (!st.error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", st.error.c_str());
}

void Studio::draw_focus_tab() {
    if (!m_doc.is_open()) {
        ImGui::TextWrapped("Open a project first.");
        return;
    }
    FocusTrack& ft = m_doc.focus();
    if (!m_depth)
        ImGui::TextWrapped("Depth appears after a fit (it is fitted to the radius maps); until then "
                           "the refocused view shows the sharp composite.");
    else
        ImGui::Text("depth fitted: rms %.2f px", m_depth->rms_px);
    ImGui::TextWrapped("Values at frame %d. Changing one sets a keyframe there.", m_frame);
    const char* easings[] = {"linear", "ease in-out", "hold"};
    int e = static_cast<int>(m_new_key_easing);
    if (ImGui::Combo("new keys", &e, easings, 3)) m_new_key_easing = static_cast<Easing>(e);
    const PreviewLens lens = ft.lens_at(m_frame, m_depth.get());
    const double current[] = {lens.focus, lens.aperture, double(lens.blades), lens.rotation_deg, lens.beta,
                              lens.highlight_gain};
    const auto& lanes = focus_lanes();
    for (size_t i = 0; i < lanes.size(); ++i) {
        float v = static_cast<float>(current[i]);
        ImGui::PushID(static_cast<int>(i));
        ImGui::SetNextItemWidth(200);
        if (ImGui::SliderFloat(lanes[i].name, &v, static_cast<float>(lanes[i].min),
                               static_cast<float>(lanes[i].max), lanes[i].format))
            guarded([&] { set_key(lanes[i].name, m_frame, v, m_new_key_easing); });
        ImGui::SameLine();
        Lane& lane = ft.*(lanes[i].lane);
        const bool keyed = std::any_of(lane.keys.begin(), lane.keys.end(),
                                       [&](const Keyframe& k) { return k.frame == m_frame; });
        if (ImGui::SmallButton(keyed ? "del" : "key")) {
            if (keyed) lane.remove(m_frame);
            else lane.set(m_frame, current[i], m_new_key_easing);
            m_doc.mark_dirty();
            m_view_dirty = true;
        }
        ImGui::PopID();
    }
    ImGui::Separator();
    if (ImGui::Button(m_pick_focus ? "click the viewer..." : "Click to focus")) {
        m_pick_focus = !m_pick_focus;
        m_pick_track = false;
        if (m_mode == ViewMode::Input) set_mode(ViewMode::Refocused);
    }
    ImGui::SameLine();
    if (ImGui::Button(m_pick_track ? "click the viewer..." : "Track a point")) {
        m_pick_track = !m_pick_track;
        m_pick_focus = false;
        if (m_mode == ViewMode::Input) set_mode(ViewMode::Refocused);
    }
    if (ft.track) {
        ImGui::Text("tracking %s point (%.3f, %.3f)", ft.track->layer ? "foreground" : "background", ft.track->u,
                    ft.track->v);
        ImGui::SetNextItemWidth(200);
        int range[2] = {ft.track->from_frame, ft.track->to_frame};
        if (ImGui::DragInt2("frames", range, 0.2f, 0, m_source ? m_source->frames() - 1 : 0)) {
            ft.track->from_frame = std::min(range[0], range[1]);
            ft.track->to_frame = std::max(range[0], range[1]);
            m_doc.mark_dirty();
            m_view_dirty = true;
        }
        if (ImGui::Button("Stop tracking")) {
            ft.track.reset();
            m_doc.mark_dirty();
            m_view_dirty = true;
        }
    }
    ImGui::TextWrapped("Rack focus: key the focus at two frames (e.g. click the background at the "
                       "first frame and the subject at a later one); ease in-out eases between them.");
}

void Studio::start_export(const nlohmann::json& req) {
    if (!m_doc.is_open()) throw Error("no project is open");
    if (!m_worker->has_engine()) throw Error("fit the project before exporting (Fit tab)");
    if (m_exporting) throw Error("an export is already running");
    std::vector<std::string> passes = req.at("what").get<std::vector<std::string>>();
    const std::string format = req.value("format", "png");
    const std::string out = req.at("out").get<std::string>();
    const int n = m_source->frames();
    const int first = req.value("first", 0), last = req.value("last", n - 1);
    if (first < 0 || first > last || last >= n)
        throw Error("export range " + std::to_string(first) + ".." + std::to_string(last) +
                    " is outside the clip's frames 0.." + std::to_string(n - 1));
    for (const auto& p : passes) parse_export_pass(p);  // refuse unknown passes now
    // The export sees the document as it is now, saved or not.
    auto edits = std::make_shared<ProjectEdits>(m_doc.edits());
    auto project = std::make_shared<Project>(m_doc.project());
    auto focus = std::make_shared<FocusTrack>(m_doc.focus());
    const double fps = m_source->fps();
    m_exporting = true;
    m_export_result.clear();
    FitWorker* w = m_worker.get();
    m_worker->post("export", [=](FitEngine* engine, const Project&) {
        std::string result;
        try {
            if (!engine) throw Error("the project has no fit to export");
            int files = 0;
            for (size_t i = 0; i < passes.size(); ++i) {
                const ExportPass pass = parse_export_pass(passes[i]);
                std::string fmt = format;
                if ((pass == ExportPass::Coc || pass == ExportPass::Uv || pass == ExportPass::Depth)) fmt = "exr";
                if (pass == ExportPass::Atlas && fmt == "mp4") fmt = "png";
                std::string target = out;
                if (fmt == "mp4") target = (fs::path(out) / (passes[i] + ".mp4")).string();
                else if (pass != ExportPass::Atlas) target = (fs::path(out) / passes[i]).string();
                fs::create_directories(fs::path(fmt == "mp4" ? fs::path(target).parent_path() : fs::path(target)));
                ExportOptions eo;
                eo.fps = fps;
                eo.project = project.get();
                eo.edits = edits.get();
                eo.focus = focus.get();
                eo.first = first;
                eo.last = last;
                eo.progress = [&](int done, int total) {
                    w->set_job_progress((i + double(done) / total) / passes.size());
                    return !w->cancelled();
                };
                auto written = export_pass(*engine, pass, fmt, target, eo);
                files += static_cast<int>(written.size());
            }
            result = "exported " + std::to_string(files) + " files to " + out;
        } catch (const std::exception& e) {
            result = std::string("export failed: ") + e.what();
        }
        w->post_result(result);
    });
}

void Studio::poll_results() {
    if (!m_exporting && !busy_with_files()) return;
    auto r = m_worker->take_result();
    if (!r) return;
    if (r->rfind("copied:", 0) == 0) {
        m_save_as_dir.clear();
        guarded([&] {
            m_doc.finish_save_as(r->substr(7));
            after_open();
            m_info = "saved as " + m_doc.project().dir.string();
        });
    } else if (r->rfind("save as failed:", 0) == 0) {
        m_save_as_dir.clear();
        after_open();  // the worker was stopped for the copy: reopen the project as it was
        set_error(r->substr(15));
    } else if (r->rfind("ingested:", 0) == 0) {
        m_ingest_dir.clear();
        guarded([&] {
            m_doc.open(r->substr(9));
            after_open();
        });
    } else if (r->rfind("ingest failed:", 0) == 0) {
        m_ingest_dir.clear();
        set_error(r->substr(14));
    } else {
        m_exporting = false;
        m_export_result = *r;
        m_info = *r;
    }
}

void Studio::draw_export_tab() {
    if (!m_doc.is_open()) {
        ImGui::TextWrapped("Open a project first.");
        return;
    }
    const FitWorker::Status st = m_worker->status();
    ImGui::BeginDisabled(m_exporting);
    for (int i = 0; i < 8; ++i) ImGui::Checkbox(kPasses[i].label, &m_exp_pass[i]);
    ImGui::Combo("format", &m_exp_format, kFormats, 4);
    ImGui::TextDisabled("radius, depth and UV are written as EXR; atlases as images");
    const int n = m_source ? m_source->frames() : 1;
    if (m_exp_last < 0) m_exp_last = n - 1;
    int range[2] = {m_exp_first, m_exp_last};
    if (ImGui::DragInt2("frames", range, 0.2f, 0, n - 1)) {
        m_exp_first = std::clamp(std::min(range[0], range[1]), 0, n - 1);
        m_exp_last = std::clamp(std::max(range[0], range[1]), 0, n - 1);
    }
    ImGui::InputText("folder", m_exp_out, sizeof m_exp_out);
    if (ImGui::Button("Export")) {
        nlohmann::json req = {{"format", kFormats[m_exp_format]}, {"out", m_exp_out},
                              {"first", m_exp_first}, {"last", m_exp_last}};
        std::vector<std::string> what;
        for (int i = 0; i < 8; ++i)
            if (m_exp_pass[i]) what.push_back(kPasses[i].name);
        req["what"] = what;
        guarded([&] { start_export(req); });
    }
    ImGui::EndDisabled();
    if (m_exporting) {
        ImGui::ProgressBar(static_cast<float>(st.job_progress), ImVec2(-1, 0));
        if (ImGui::Button("Cancel")) m_worker->cancel_job();
        ImGui::TextDisabled("files are complete or absent: a cancelled sequence is removed");
    }
    if (!m_export_result.empty()) ImGui::TextWrapped("%s", m_export_result.c_str());
}

void Studio::draw_log_tab() {
    const FitWorker::Status st = m_worker->status(true);
    ImGui::Text("longest UI frame: %.1f ms (during a fit: %.1f ms)", m_longest_frame_ms,
                m_longest_fit_frame_ms);
    ImGui::Text("last GLSL preview render: %.1f ms", m_last_preview_ms);
    ImGui::BeginChild("log", ImVec2(0, 0), true);
    for (const auto& l : st.log) ImGui::TextWrapped("%s", l.c_str());
    if (ImGui::GetScrollY() >= ImGui::GetScrollMaxY()) ImGui::SetScrollHereY(1.0f);
    ImGui::EndChild();
}

}  // namespace refocus
