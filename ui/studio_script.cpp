#include "studio_script.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <csignal>
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
    for (auto group :
         {&StudioScript::project_step, &StudioScript::view_step, &StudioScript::edit_step,
          &StudioScript::check_step, &StudioScript::file_step})
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
            return !f.value("wait", true);  // "wait": false goes on while the fit runs
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
    if (step.contains("play")) return play_step(st, step["play"], first);
    if (step.contains("preview_renderer")) {
        const std::string b = step["preview_renderer"];
        if (b != "auto" && b != "gpu" && b != "cpu")
            throw Error("preview_renderer is auto, gpu or cpu, not '" + b + "'");
        if (first)
            st.m_ctx.renderer->set_backend(b == "gpu"   ? ViewRenderer::Backend::Gpu
                                           : b == "cpu" ? ViewRenderer::Backend::Cpu
                                                        : ViewRenderer::Backend::Auto);
        return m_settle > 2;
    }
    if (step.contains("preview_quality")) {
        const std::string q = step["preview_quality"];
        if (q != "fast" && q != "exact")
            throw Error("preview_quality is fast or exact, not '" + q + "'");
        if (first)
            st.m_ctx.renderer->set_quality(q == "fast" ? PreviewQuality::Fast
                                                       : PreviewQuality::Exact);
        return m_settle > 2;
    }
    if (step.contains("proxy")) {
        const std::string p = step["proxy"];
        const int d = p == "auto" ? 0 : p == "full" ? 1 : p == "half" ? 2 : p == "quarter" ? 4 : -1;
        if (d < 0) throw Error("proxy is auto, full, half or quarter, not '" + p + "'");
        if (first) st.m_ctx.renderer->set_proxy(d);
        return st.view_current() || !st.m_viewer.mode->needs_fit;
    }
    if (step.contains("window_size")) {
        // As a user drags the window's corner; the panels follow the new size.
        if (first)
            glfwSetWindowSize(st.m_window, step["window_size"].at(0), step["window_size"].at(1));
        return m_settle > 4;
    }
    if (step.contains("layout")) {
        const json& l = step["layout"];
        st.m_ctx.layout.side_w = l.value("side_width", st.m_ctx.layout.side_w);
        st.m_ctx.layout.timeline_h = l.value("timeline_height", st.m_ctx.layout.timeline_h);
        return m_settle > 2;
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

// Plays `frames` frames from `from` as a user's Space does, after the renderer cached the clip
// when `cache` (as an editor's render cache); prints what was shown for scripts to read.
bool StudioScript::play_step(Studio& st, const json& p, bool first) {
    StudioContext& ctx = st.m_ctx;
    if (first) {
        st.play(false);
        st.set_frame(p.value("from", 0));
        m_play_started = false;
    }
    if (!m_play_started) {
        if (first) m_step_clock = glfwGetTime();
        if (p.value("cache", true)) {
            for (int m : wanted_modes(st.m_viewer))
                if (ctx.renderer->cached_frames(m) < ctx.source->frames()) return false;
            if (!st.view_current()) return false;
        }
        ctx.playback = PlaybackStats{};
        st.play(true);
        m_play_started = true;
        std::printf("playback: cached in %.1f s (%s, %.0f ms a frame)\n",
                    glfwGetTime() - m_step_clock, ctx.renderer->backend_name().c_str(),
                    ctx.renderer->last_full_ms(wanted_modes(st.m_viewer)[0]));
        return false;
    }
    if (ctx.playback.played < p.value("frames", ctx.source->frames())) return false;
    st.play(false);
    std::printf("playback: %zu distinct frames of %d\n", ctx.playback.pictures.size(),
                ctx.playback.played);
    std::fflush(stdout);
    const int min = p.value("min_distinct", 0);
    if (static_cast<int>(ctx.playback.pictures.size()) < min)
        throw Error("playback showed " + std::to_string(ctx.playback.pictures.size()) +
                    " distinct pictures, expected at least " + std::to_string(min));
    return true;
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
        if (e.contains("autosave_offered") &&
            e["autosave_offered"].get<bool>() != ctx.doc.has_newer_autosave())
            throw Error(std::string("expected ") +
                        (e["autosave_offered"].get<bool>() ? "" : "no ") +
                        "autosave to be offered");
        if (e.contains("modified") && e["modified"].get<bool>() != ctx.doc.dirty())
            throw Error(std::string("expected the project ") +
                        (e["modified"].get<bool>() ? "modified" : "unmodified"));
        return true;
    }
    if (step.contains("stats")) {
        const FrameTimes& t = st.times();
        json s = {{"longest_frame_ms", t.longest_frame_ms},
                  {"longest_frame_during_fit_ms", t.longest_fit_frame_ms},
                  {"longest_busy_frame_ms", t.longest_busy_frame_ms},
                  {"busy_frames", t.busy_frames},
                  {"frames", t.frames_drawn}};
        write_file_atomic(step["stats"].get<std::string>(), s.dump(2));
        // Frames drawn while a fit, playback or an export ran; then every frame of the run.
        std::printf("longest UI frame: %.1f ms\n", t.longest_busy_frame_ms);
        std::printf("longest UI frame of the whole run: %.1f ms (%d frames, %d busy)\n",
                    t.longest_frame_ms, t.frames_drawn, t.busy_frames);
        std::fflush(stdout);
        return true;
    }
    if (step.contains("autosave")) {
        // What the studio does a minute after a change, now.
        if (!ctx.doc.autosave_if_due(glfwGetTime(), 0.0)) throw Error("nothing to autosave");
        return true;
    }
    if (step.contains("crash")) {
        // Dies as under kill -9: no destructor runs, nothing is saved or checkpointed.
        std::fflush(stdout);
        std::raise(SIGKILL);
    }
    if (step.contains("touch")) {
        // A file for a test harness to wait on (it kills the studio when it appears).
        write_file_atomic(step["touch"].get<std::string>(), "");
        return true;
    }
    if (step.contains("wait_fitting")) {
        return ctx.worker->status().state == FitWorker::State::Fitting &&
               ctx.worker->status().snap.step >= step["wait_fitting"].get<int>();
    }
    if (step.contains("restore_autosave")) {
        if (!ctx.doc.has_newer_autosave()) throw Error("no autosave was offered");
        ctx.doc.restore_autosave();
        ctx.view_dirty = true;
        return true;
    }
    if (step.contains("quit")) return true;
    return std::nullopt;
}

// drop, browser: through the same code as a drop on the window and a click in the browser.
std::optional<bool> StudioScript::file_step(Studio& st, const json& step, bool first) {
    DialogState& d = st.m_dialogs;
    const bool settled = !st.ingesting() && !st.saving_as() && worker_idle(st) &&
                         d.pending == DialogState::Pending::None;
    if (step.contains("drop")) {
        if (first) st.drop({step["drop"].get<std::string>()});
        if (!d.dropped.empty() || m_settle < 3) return false;
        return settled && st.m_ctx.doc.is_open();
    }
    if (!step.contains("browser")) return std::nullopt;
    const json& b = step["browser"];
    if (b.is_boolean()) {
        if (b.get<bool>()) throw Error("\"browser\" is an object ({\"dialog\": ...}) or false");
        if (first) d.browser.close(), st.m_atlas.browser().close();
        return !d.browser.is_open() && !st.m_atlas.browser().is_open();
    }
    using B = DialogState::Browse;
    const std::string dialog = b.value("dialog", "open");
    const bool atlas = dialog == "atlas_export" || dialog == "atlas_import";
    FileBrowser& fb = atlas ? st.m_atlas.browser() : d.browser;
    if (first && atlas) {
        st.m_viewer.show_atlas = true;  // the panel draws its browser
        if (dialog == "atlas_export")
            st.m_atlas.ask_export(b.value("dir", ""));
        else
            st.m_atlas.ask_import(b.value("dir", ""));
    } else if (first) {
        const B what = dialog == "open"         ? B::Open
                       : dialog == "new"        ? B::NewClip
                       : dialog == "new_folder" ? B::NewFolder
                       : dialog == "save_as"    ? B::SaveAs
                                                : B::None;
        if (what == B::None)
            throw Error("unknown browser dialog '" + dialog +
                        "' (open, new, new_folder, save_as, atlas_export, atlas_import)");
        st.browse(what, false, b.value("dir", ""));
    }
    if (m_settle < 3) return false;  // drawn
    if (m_settle == 3) {
        const FolderListing& l = fb.listing();
        if (!l.error.empty()) throw Error(l.error);
        for (const std::string& name : b.value("shows", std::vector<std::string>{})) {
            bool found = false;
            for (const FolderEntry& e : l.entries) found |= e.name == name;
            if (!found) throw Error("the browser on " + l.dir + " does not list " + name);
        }
        if (b.contains("select") && !fb.select(b["select"].get<std::string>()))
            throw Error("the browser on " + l.dir + " has no " + b["select"].dump() + " to select");
        if (b.contains("pick") && !fb.accept(b["pick"].get<std::string>()))
            throw Error("the browser on " + l.dir + " cannot pick " + b["pick"].dump() + ": " +
                        (fb.problem().empty() ? "not listed" : fb.problem()));
    }
    if (atlas && b.contains("pick") && !fb.is_open() && m_settle > 5) {
        if (!st.m_atlas.error().empty()) throw Error(st.m_atlas.error());
        return true;
    }
    // A folder picked is entered (the browser stays); anything else is done when it is handled.
    if (!b.contains("pick") || fb.is_open()) return m_settle > 5;
    return d.browsing == B::None && settled;
}

}  // namespace refocus
