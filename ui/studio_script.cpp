#include "studio_script.h"

#include <GLFW/glfw3.h>

#include <cstdio>
#include <cstdlib>

#include "io/image_file.h"
#include "studio_app.h"
#include "util/error.h"

namespace refocus {

using nlohmann::json;

namespace {
// "${NAME}" in string values → the environment variable (scripts name files portably).
void expand_env(json& j) {
    if (j.is_string()) {
        std::string v = j.get<std::string>(), out;
        for (size_t i = 0; i < v.size();) {
            size_t b = v.find("${", i);
            if (b == std::string::npos) {
                out += v.substr(i);
                break;
            }
            size_t e = v.find('}', b);
            if (e == std::string::npos) throw Error("unterminated ${ in script value \"" + v + "\"");
            const std::string name = v.substr(b + 2, e - b - 2);
            const char* val = std::getenv(name.c_str());
            if (!val) throw Error("script uses ${" + name + "} but the environment does not set it");
            out += v.substr(i, b - i) + val;
            i = e + 1;
        }
        j = out;
    } else if (j.is_structured()) {
        for (auto& el : j) expand_env(el);
    }
}

Easing parse_easing(const std::string& e) {
    if (e == "linear") return Easing::Linear;
    if (e == "ease" || e == "ease-in-out") return Easing::EaseInOut;
    if (e == "hold") return Easing::Hold;
    throw Error("unknown easing '" + e + "' (linear, ease, hold)");
}
}  // namespace

StudioScript::StudioScript(const std::string& path) : m_path(path) {
    try {
        m_steps = json::parse(read_text_file(path));
    } catch (const json::exception& e) {
        throw Error(file_error(path, std::string("not a valid script: ") + e.what()));
    }
    if (m_steps.is_object() && m_steps.contains("steps")) m_steps = m_steps["steps"];
    if (!m_steps.is_array()) throw Error(file_error(path, "a script is a JSON list of steps"));
    try {
        expand_env(m_steps);
    } catch (const Error& e) {
        throw Error(file_error(path, e.what()));
    }
}


int StudioScript::advance(Studio& studio) {
    while (m_index < m_steps.size()) {
        const json& step = m_steps[m_index];
        const double now = glfwGetTime();
        if (!m_started) {
            m_started = true;
            m_step_start = now;
            m_settle = 0;
            std::fprintf(stderr, "script: step %zu: %s\n", m_index + 1, step.dump().c_str());
        }
        bool done = false;
        try {
            if (!studio.last_error().empty()) throw Error(studio.last_error());
            done = run_step(studio, step);
        } catch (const std::exception& e) {
            std::fprintf(stderr, "refocus-studio: %s: step %zu %s failed: %s\n", m_path.c_str(),
                         m_index + 1, step.dump().c_str(), e.what());
            return 1;
        }
        const double limit = step.is_object() && step.contains("timeout") ? step["timeout"].get<double>() : 900.0;
        if (!done) {
            if (now - m_step_start > limit) {
                std::fprintf(stderr, "refocus-studio: %s: step %zu timed out after %.0f s\n", m_path.c_str(),
                             m_index + 1, limit);
                return 1;
            }
            return -1;  // wait for more frames
        }
        ++m_index;
        m_started = false;
        if (step.contains("quit")) return 0;
        return -1;  // one step per frame: the UI shows each change
    }
    return 0;
}

bool StudioScript::run_step(Studio& st, const json& step) {
    auto first = m_settle++ == 0;
    FitWorker& w = st.worker();
    auto worker_idle = [&] {
        auto s = w.status();
        if (!s.error.empty() && s.state == FitWorker::State::Failed) throw Error(s.error);
        return !s.busy && s.state != FitWorker::State::Preparing && s.state != FitWorker::State::Fitting &&
               s.state != FitWorker::State::Paused;
    };
    if (step.contains("open")) {
        if (first) st.open_project(step["open"].get<std::string>());
        return worker_idle() && (st.view_current() || !w.has_engine());
    }
    if (step.contains("new")) {
        if (first) st.new_project(step["new"].at("clip"), step["new"].at("project"));
        return !st.ingesting() && st.m_doc.is_open() && worker_idle();
    }
    if (step.contains("fit")) {
        const json& f = step["fit"];
        if (first) {
            st.m_preset = 0;
            const std::string preset = f.value("preset", "fast");
            const char* names[] = {"fast", "paper", "perframe"};
            for (int i = 0; i < 3; ++i)
                if (preset == names[i]) st.m_preset = i;
            st.m_use_iters = f.contains("iters");
            st.m_budget_iters = f.value("iters", 0);
            st.m_budget_minutes = f.value("minutes", 1.0f);
            st.start_fit(f.value("resume", false));
            return false;
        }
        if (m_settle < 3) return false;  // let the worker pick the job up
        if (!worker_idle()) return false;
        if (!w.has_engine()) throw Error("the fit ended without a fitted engine: " + w.status().error);
        return true;
    }
    if (step.contains("wait_depth")) return st.m_depth != nullptr && st.view_current();
    if (step.contains("frame")) {
        if (first) st.set_frame(step["frame"].get<int>());
        return st.view_current() || st.m_mode == ViewMode::Input;
    }
    if (step.contains("mode")) {
        if (first) st.set_mode(parse_view_mode(step["mode"]));
        return st.view_current() || st.m_mode == ViewMode::Input;
    }
    if (step.contains("atlas_view")) {
        st.m_show_atlas = step["atlas_view"].get<bool>();
        return m_settle > 2;  // drawn
    }
    if (step.contains("time_slice")) {
        if (step["time_slice"].is_boolean() && !step["time_slice"].get<bool>()) {
            st.m_time_slice = false;
            return true;
        }
        if (first) {
            st.m_time_slice = true;
            st.m_slice_row = step["time_slice"].value("row", -1);
            st.m_slice_dirty = true;
        }
        if (!(m_settle > 3 && !st.m_slice_job && !st.m_slice_key.empty())) return false;
        if (step["time_slice"].contains("save"))
            write_image_file(step["time_slice"]["save"].get<std::string>(), st.m_slice_image, PixelFormat::Png8);
        return true;
    }
    if (step.contains("split")) {
        if (first) {
            const json& sp = step["split"];
            st.m_split_a = parse_view_mode(sp.value("left", "input"));
            st.m_split_b = parse_view_mode(sp.value("right", "refocused"));
            st.m_split = sp.value("wipe", 0.5f);
            st.set_mode(ViewMode::Split);
        }
        return st.view_current();
    }
    if (step.contains("key")) {
        const json& k = step["key"];
        st.set_key(k.at("lane"), k.at("frame"), k.at("value"), parse_easing(k.value("easing", "ease")));
        return true;
    }
    if (step.contains("focus_click") || step.contains("track_click")) {
        const json& c = step.contains("focus_click") ? step["focus_click"] : step["track_click"];
        if (first) st.set_frame(c.at("frame"));
        if (!(st.view_current() && st.m_depth)) return false;
        if (step.contains("focus_click")) st.focus_at_pixel(c.at("frame"), c.at("x"), c.at("y"));
        else st.track_pixel(c.at("frame"), c.at("x"), c.at("y"));
        return true;
    }
    if (step.contains("paint")) {
        const json& p = step["paint"];
        Brush b;
        auto col = p.value("color", std::vector<float>{1, 0, 0});
        if (col.size() != 3) throw Error("paint.color needs 3 values");
        for (int c = 0; c < 3; ++c) b.color[c] = col[c];
        b.size = p.value("size", 8.0f);
        b.hardness = p.value("hardness", 1.0f);
        b.opacity = p.value("opacity", 1.0f);
        std::vector<std::array<float, 2>> pts;
        for (const auto& q : p.at("points")) pts.push_back({q.at(0).get<float>(), q.at(1).get<float>()});
        const int layer = p.value("layer", "bg") == "fg" ? 1 : 0;
        if (st.m_doc.edits().layer(layer).width() == 0) return false;  // atlases not here yet
        if (!st.m_atlas_panel.paint_stroke(layer, pts, b)) throw Error("the paint stroke was refused");
        st.m_doc.mark_dirty();
        return true;
    }
    if (step.contains("export")) {
        if (first) {
            st.start_export(step["export"]);
            return false;
        }
        if (st.exporting()) return false;
        if (st.export_result().rfind("export failed", 0) == 0) throw Error(st.export_result());
        return true;
    }
    if (step.contains("save")) {
        st.save();
        return true;
    }
    if (step.contains("save_as")) {
        if (first) st.save_as(step["save_as"]);
        return !st.saving_as() && worker_idle();
    }
    if (step.contains("reopen")) {
        if (first) {
            const std::string dir = st.m_doc.project().dir.string();
            st.m_doc.close();
            st.open_project(dir);
        }
        return worker_idle() && (st.view_current() || !w.has_engine());
    }
    if (step.contains("screenshot")) {
        if (!(st.view_current() || st.m_mode == ViewMode::Input)) return false;
        if (m_settle < 3) return false;  // two drawn frames with the final image
        st.screenshot(step["screenshot"]);
        return true;
    }
    if (step.contains("expect")) {
        const json& e = step["expect"];
        if (e.contains("keys"))
            for (auto& [lane, count] : e["keys"].items()) {
                int have = -1;
                for (const LaneInfo& l : focus_lanes())
                    if (lane == l.name) have = static_cast<int>((st.m_doc.focus().*(l.lane)).keys.size());
                if (have != count.get<int>())
                    throw Error("expected " + count.dump() + " keys on lane " + lane + ", found " +
                                std::to_string(have));
            }
        if (e.contains("edits") && e["edits"].get<bool>() != st.m_doc.edits().has_edits())
            throw Error(std::string("expected ") + (e["edits"].get<bool>() ? "" : "no ") + "atlas edits");
        if (e.contains("fitted") && e["fitted"].get<bool>() != w.has_engine())
            throw Error("expected the project to be fitted");
        if (e.contains("track") && e["track"].get<bool>() != st.m_doc.focus().track.has_value())
            throw Error("expected a tracked focus point");
        return true;
    }
    if (step.contains("stats")) {
        json s = {{"longest_frame_ms", st.longest_frame_ms()},
                  {"longest_frame_during_fit_ms", st.longest_frame_during_fit_ms()},
                  {"last_preview_ms", st.last_preview_ms()}};
        write_file_atomic(step["stats"].get<std::string>(), s.dump(2));
        return true;
    }
    if (step.contains("quit")) return true;
    throw Error("unknown step " + step.dump());
}

}  // namespace refocus
