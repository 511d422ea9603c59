#include "studio_script.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>

#include "edit_menu.h"
#include "io/image_file.h"
#include "studio_app.h"
#include "studio_presets.h"
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
            if (e == std::string::npos)
                throw Error("unterminated ${ in script value \"" + v + "\"");
            const std::string name = v.substr(b + 2, e - b - 2);
            const char* val = std::getenv(name.c_str());
            if (!val)
                throw Error("script uses ${" + name + "} but the environment does not set it");
            out += v.substr(i, b - i) + val;
            i = e + 1;
        }
        j = out;
    } else if (j.is_structured()) {
        for (auto& el : j) expand_env(el);
    }
}

Easing parse_easing(const std::string& e) {
    Easing out;
    if (e == "ease" || e == "ease-in-out") return Easing::EaseInOut;
    if (e == "ease-in") return Easing::EaseIn;
    if (e == "ease-out") return Easing::EaseOut;
    if (parse_easing_name(e, out)) return out;
    throw Error("unknown easing '" + e + "' (linear, ease, ease_in, ease_out, hold)");
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
        const double limit =
            step.is_object() && step.contains("timeout") ? step["timeout"].get<double>() : 900.0;
        if (!done) {
            if (now - m_step_start > limit) {
                std::fprintf(stderr, "refocus-studio: %s: step %zu timed out after %.0f s\n",
                             m_path.c_str(), m_index + 1, limit);
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
    const bool first = m_settle++ == 0;
    // The step's kind is its key; each group below answers for its own keys.
    for (auto group : {&StudioScript::project_step, &StudioScript::view_step,
                       &StudioScript::edit_step, &StudioScript::check_step})
        if (std::optional<bool> done = (this->*group)(st, step, first)) return *done;
    throw Error("unknown step " + step.dump());
}

bool StudioScript::worker_idle(Studio& st) const {
    auto s = st.m_ctx.worker->status();
    if (!s.error.empty() && s.state == FitWorker::State::Failed) throw Error(s.error);
    return !s.busy && s.state != FitWorker::State::Preparing &&
           s.state != FitWorker::State::Fitting && s.state != FitWorker::State::Paused;
}

// open, new, fit, wait_depth, save, save_as, reopen.
std::optional<bool> StudioScript::project_step(Studio& st, const json& step, bool first) {
    StudioContext& ctx = st.m_ctx;
    if (step.contains("open")) {
        if (first) st.open_project(step["open"].get<std::string>());
        return worker_idle(st) && (st.view_current() || !ctx.worker->has_engine());
    }
    if (step.contains("new")) {
        if (first) st.new_project(step["new"].at("clip"), step["new"].at("project"));
        return !st.ingesting() && ctx.doc.is_open() && worker_idle(st);
    }
    if (step.contains("fit")) {
        const json& f = step["fit"];
        if (first) {
            st.m_fit.preset = std::max(0, studio_preset_index(f.value("preset", "fast")));
            st.m_fit.use_iters = f.contains("iters");
            st.m_fit.budget_iters = f.value("iters", 0);
            st.m_fit.budget_minutes = f.value("minutes", 1.0f);
            st.start_fit(f.value("resume", false));
            return false;
        }
        if (m_settle < 3) return false;  // let the worker pick the job up
        if (!worker_idle(st)) return false;
        if (!ctx.worker->has_engine())
            throw Error("the fit ended without a fitted engine: " + ctx.worker->status().error);
        return true;
    }
    if (step.contains("wait_depth")) return ctx.depth != nullptr && st.view_current();
    if (step.contains("save")) {
        st.save();
        return true;
    }
    if (step.contains("save_as")) {
        if (first) st.save_as(step["save_as"]);
        return !st.saving_as() && worker_idle(st);
    }
    if (step.contains("reopen")) {
        if (first) {
            const std::string dir = ctx.doc.project().dir.string();
            ctx.doc.close();
            st.open_project(dir);
        }
        return worker_idle(st) && (st.view_current() || !ctx.worker->has_engine());
    }
    return std::nullopt;
}

// frame, mode, atlas_view, time_slice, split.
std::optional<bool> StudioScript::view_step(Studio& st, const json& step, bool first) {
    ViewerState& v = st.m_viewer;
    if (step.contains("frame")) {
        if (first) st.set_frame(step["frame"].get<int>());
        return st.view_current() || !v.mode->needs_fit;
    }
    if (step.contains("mode")) {
        if (first) st.set_mode(view_mode(step["mode"]));
        return st.view_current() || !v.mode->needs_fit;
    }
    if (step.contains("atlas_view")) {
        v.show_atlas = step["atlas_view"].get<bool>();
        return m_settle > 2;  // drawn
    }
    if (step.contains("time_slice")) {
        const json& ts = step["time_slice"];
        if (ts.is_boolean() && !ts.get<bool>()) {
            v.slice.on = false;
            return true;
        }
        if (first) {
            v.slice.on = true;
            v.slice.row = ts.value("row", -1);
            v.slice.dirty = true;
        }
        if (!(m_settle > 3 && !v.slice.job && !v.slice.key.empty())) return false;
        if (ts.contains("save"))
            write_image_file(ts["save"].get<std::string>(), v.slice.image, PixelFormat::Png8);
        return true;
    }
    if (step.contains("split")) {
        if (first) {
            const json& sp = step["split"];
            v.split_a = &view_mode(sp.value("left", "input"));
            v.split_b = &view_mode(sp.value("right", "refocused"));
            v.split = sp.value("wipe", 0.5f);
            st.set_mode(view_mode("split"));
        }
        return st.view_current();
    }
    return std::nullopt;
}

// key, move_key, delete_key, undo, redo, focus_click, track_click, paint, export.
std::optional<bool> StudioScript::edit_step(Studio& st, const json& step, bool first) {
    StudioContext& ctx = st.m_ctx;
    if (step.contains("key")) {
        const json& k = step["key"];
        st.set_key(k.at("lane"), k.at("frame"), k.at("value"),
                   parse_easing(k.value("easing", "ease")));
        ctx.doc.commit("Key " + k.at("lane").get<std::string>());
        return true;
    }
    if (step.contains("move_key")) {
        const json& k = step["move_key"];
        move_key(ctx, k.at("lane"), k.at("from"), k.at("to"));
        return true;
    }
    if (step.contains("delete_key")) {
        delete_key(ctx, step["delete_key"].at("lane"), step["delete_key"].at("frame"));
        return true;
    }
    if (step.contains("undo") || step.contains("redo")) {
        const bool undo = step.contains("undo");
        if (!(undo ? undo_document(ctx) : redo_document(ctx)))
            throw Error(std::string("nothing to ") + (undo ? "undo" : "redo"));
        return true;
    }
    if (step.contains("focus_click") || step.contains("track_click")) {
        const json& c = step.contains("focus_click") ? step["focus_click"] : step["track_click"];
        if (first) st.set_frame(c.at("frame"));
        if (!(st.view_current() && ctx.depth)) return false;
        if (step.contains("focus_click"))
            st.focus_at_pixel(c.at("frame"), c.at("x"), c.at("y"));
        else
            st.track_pixel(c.at("frame"), c.at("x"), c.at("y"));
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
        for (const auto& q : p.at("points"))
            pts.push_back({q.at(0).get<float>(), q.at(1).get<float>()});
        const int layer = p.value("layer", "bg") == "fg" ? 1 : 0;
        if (ctx.doc.edits().layer(layer).width() == 0) return false;  // atlases not here yet
        if (!st.m_atlas.paint_stroke(layer, pts, b)) throw Error("the paint stroke was refused");
        ctx.doc.mark_dirty();
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
    return std::nullopt;
}

namespace {
// The expectations on the document: "dirty", "undo" / "redo" (the labels of the entries next
// in line, "" for none), "key_frames" ({lane: [frames]}), "easing" ({lane: [easing names]}).
void expect_document(StudioContext& ctx, const json& e) {
    if (e.contains("dirty") && e["dirty"].get<bool>() != ctx.doc.dirty())
        throw Error(std::string("expected the document ") +
                    (e["dirty"].get<bool>() ? "modified" : "unmodified"));
    for (const char* which : {"undo", "redo"}) {
        if (!e.contains(which)) continue;
        const std::string have = which[0] == 'u' ? ctx.doc.undo_label() : ctx.doc.redo_label();
        if (have != e[which].get<std::string>())
            throw Error(std::string("expected ") + which + " '" + e[which].get<std::string>() +
                        "', found '" + have + "'");
    }
    for (const char* what : {"key_frames", "easing"}) {
        if (!e.contains(what)) continue;
        for (auto& [lane, want] : e[what].items()) {
            json have = json::array();
            const Lane& l = ctx.doc.focus().*(focus_lanes()[focus_lane_index(lane)].lane);
            for (const Keyframe& k : l.keys)
                have.push_back(what[0] == 'k' ? json(k.frame) : json(easing_name(k.easing)));
            if (have != want)
                throw Error(std::string("expected ") + what + " " + want.dump() + " on lane " +
                            lane + ", found " + have.dump());
        }
    }
}
}  // namespace

// screenshot, expect, stats, quit.
std::optional<bool> StudioScript::check_step(Studio& st, const json& step, bool) {
    StudioContext& ctx = st.m_ctx;
    if (step.contains("screenshot")) {
        if (!(st.view_current() || !st.m_viewer.mode->needs_fit)) return false;
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
                    if (lane == l.name)
                        have = static_cast<int>((ctx.doc.focus().*(l.lane)).keys.size());
                if (have != count.get<int>())
                    throw Error("expected " + count.dump() + " keys on lane " + lane + ", found " +
                                std::to_string(have));
            }
        if (e.contains("edits") && e["edits"].get<bool>() != ctx.doc.edits().has_edits())
            throw Error(std::string("expected ") + (e["edits"].get<bool>() ? "" : "no ") +
                        "atlas edits");
        if (e.contains("fitted") && e["fitted"].get<bool>() != ctx.worker->has_engine())
            throw Error("expected the project to be fitted");
        if (e.contains("track") && e["track"].get<bool>() != ctx.doc.focus().track.has_value())
            throw Error("expected a tracked focus point");
        expect_document(ctx, e);
        return true;
    }
    if (step.contains("stats")) {
        const FrameTimes& t = st.times();
        json s = {{"longest_frame_ms", t.longest_frame_ms},
                  {"longest_frame_during_fit_ms", t.longest_fit_frame_ms},
                  {"last_preview_ms", t.last_preview_ms}};
        write_file_atomic(step["stats"].get<std::string>(), s.dump(2));
        return true;
    }
    if (step.contains("quit")) return true;
    return std::nullopt;
}

}  // namespace refocus
