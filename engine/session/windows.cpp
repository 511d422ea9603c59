#include "session/windows.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include "edit/atlas_edit.h"
#include "io/image_file.h"
#include "prepare/log.h"
#include "util/error.h"
#include "util/json_file.h"

namespace refocus {

bool WindowedShot::is_windowed(const fs::path& dir) {
    return fs::is_regular_file(dir / kFileName) && !fs::exists(dir / Project::kFileName);
}

WindowedShot WindowedShot::load(const fs::path& dir) {
    const std::string label = (dir / kFileName).string();
    const nlohmann::json j = read_json_file(dir / kFileName);
    WindowedShot s;
    s.dir = dir;
    try {
        s.clip = j.at("clip").get<std::string>();
        s.frames = j.at("frames").get<int>();
        s.window = j.at("window").get<int>();
        s.overlap = j.at("overlap").get<int>();
        for (const auto& w : j.at("windows"))
            s.windows.push_back({w.at("first").get<int>(), w.at("last").get<int>(),
                                 w.at("dir").get<std::string>()});
    } catch (const std::exception& e) {
        throw Error(
            file_error(label, std::string("is not a shot's windows: ") + json_error_text(e)));
    }
    // The windows must cover the frames in order, each overlapping the next.
    bool ok = s.frames > 0 && !s.windows.empty() && s.windows.front().first == 0 &&
              s.windows.back().last == s.frames - 1;
    for (size_t k = 0; ok && k < s.windows.size(); ++k) {
        const ShotWindow& w = s.windows[k];
        ok = w.first <= w.last && !w.dir.empty() && fs::path(w.dir).is_relative() &&
             w.dir.find("..") == std::string::npos;
        if (ok && k > 0) ok = w.first > s.windows[k - 1].first && w.first <= s.windows[k - 1].last;
        if (ok && k > 1) ok = w.first > s.windows[k - 2].last;
    }
    if (!ok)
        throw Error(file_error(label, "the windows do not cover frames 0.." +
                                          std::to_string(s.frames - 1) +
                                          " in order, each overlapping the next"));
    return s;
}

void WindowedShot::save() const {
    nlohmann::json j = {{"clip", clip},
                        {"frames", frames},
                        {"window", window},
                        {"overlap", overlap},
                        {"windows", nlohmann::json::array()}};
    for (const auto& w : windows)
        j["windows"].push_back({{"first", w.first}, {"last", w.last}, {"dir", w.dir}});
    write_file_atomic(dir / kFileName, j.dump(2) + "\n");
}

std::vector<ShotWindow> plan_windows(int frames, int window, int overlap) {
    if (window < 2 * overlap || overlap < 1)
        throw Error("windows of " + std::to_string(window) + " frames cannot overlap by " +
                    std::to_string(overlap) + " (window >= 2 x overlap, overlap >= 1)");
    const int n =
        frames <= window ? 1 : (frames - overlap + (window - overlap) - 1) / (window - overlap);
    const int len = (frames + (n - 1) * overlap + n - 1) / n;  // <= window
    std::vector<ShotWindow> out;
    for (int k = 0; k < n; ++k) {
        char name[32];
        std::snprintf(name, sizeof name, "windows/w%02d", k);
        const int a = k * (len - overlap);
        out.push_back({a, k == n - 1 ? frames - 1 : std::min(a + len - 1, frames - 1), name});
    }
    return out;
}

std::vector<std::pair<int, float>> window_weights(const std::vector<ShotWindow>& w, int t) {
    std::vector<int> in;
    for (int k = 0; k < int(w.size()); ++k)
        if (w[k].first <= t && t <= w[k].last) in.push_back(k);
    if (in.size() == 1) return {{in[0], 1.0f}};
    if (in.size() != 2)
        throw Error("frame " + std::to_string(t) + " is in " + std::to_string(in.size()) +
                    " windows");
    const ShotWindow &a = w[in[0]], &b = w[in[1]];
    const int n = a.last - b.first + 1;
    const float later = float(t - b.first + 1) / float(n + 1);
    return {{in[0], 1.0f - later}, {in[1], later}};
}

namespace {

// A window's fit, open for export while the frames pass through it.
struct OpenWindow {
    Project project;
    ProjectEdits edits;
    std::unique_ptr<FitEngine> engine;
    ExportOptions opts;
    std::unique_ptr<PassFrames> frames;
};

}  // namespace

std::vector<std::string> export_windowed(const WindowedShot& shot, ExportPass pass,
                                         const std::string& format, const std::string& out,
                                         const std::function<bool(int, int)>& progress) {
    const std::string name = export_pass_name(pass);
    if (pass == ExportPass::Atlas || pass == ExportPass::Uv || pass == ExportPass::Parallax)
        throw Error(file_error(shot.dir.string(),
                               "--what " + name +
                                   " is each window's own (its atlas): export it from a window's "
                                   "project, " +
                                   (shot.dir / shot.windows[0].dir).string()));
    const fs::path target = fs::absolute(out).lexically_normal();
    const fs::path home = fs::absolute(shot.dir).lexically_normal();
    const fs::path rel = target.lexically_relative(home);
    if (rel.empty() || *rel.begin() != "..")
        throw Error(file_error(out, "is inside the shot's folder " + shot.dir.string() +
                                        ": write the export elsewhere"));
    const ClipFormat cf = pass_clip_format(pass, format);
    // Every window fitted before any frame is written.
    std::vector<Project> projects;
    for (const auto& w : shot.windows) {
        projects.push_back(Project::load(shot.dir / w.dir));
        if (projects.back().frames != w.last - w.first + 1)
            throw Error(file_error(projects.back().project_file().string(),
                                   "holds " + std::to_string(projects.back().frames) +
                                       " frames; its window is frames " + std::to_string(w.first) +
                                       ".." + std::to_string(w.last)));
        if (!fs::exists(fit_dir(projects.back()) / "checkpoint.json"))
            throw Error(file_error((shot.dir / w.dir).string(),
                                   "is not fitted yet: fit every window before the export"));
    }
    std::vector<std::unique_ptr<OpenWindow>> open(shot.windows.size());
    auto window = [&](int k) -> OpenWindow& {
        if (!open[k]) {
            auto o = std::make_unique<OpenWindow>();
            o->project = projects[k];
            o->edits = ProjectEdits::load(o->project);
            PrepareLog log;
            o->engine = open_fitted(o->project, log);
            o->opts.fps = o->project.fps;
            o->opts.project = &o->project;
            o->opts.edits = &o->edits;
            o->frames =
                std::make_unique<PassFrames>(*o->engine, pass, cf == ClipFormat::Mp4, o->opts);
            open[k] = std::move(o);
        }
        return *open[k];
    };
    ClipWriter writer(out, name, cf, pass_write_options(pass, projects[0].fps));
    for (int t = 0; t < shot.frames; ++t) {
        Image frame;
        for (const auto& [k, weight] : window_weights(shot.windows, t)) {
            const Image f = window(k).frames->frame(t - shot.windows[k].first);
            if (frame.pixels.empty()) {
                frame = f;
                for (float& v : frame.pixels) v *= weight;
            } else {
                if (!frame.same_shape(f))
                    throw Error(file_error((shot.dir / shot.windows[k].dir).string(),
                                           "frames differ in size from the previous window's"));
                for (size_t i = 0; i < frame.pixels.size(); ++i)
                    frame.pixels[i] += weight * f.pixels[i];
            }
        }
        for (int k = 0; k < int(open.size()); ++k)  // a window behind the playhead is done
            if (open[k] && shot.windows[k].last < t + 1) open[k].reset();
        refuse_nonfinite(frame, name, t);
        writer.write(frame);
        if (progress && !progress(t + 1, shot.frames)) {
            writer.cancel();
            throw Error("export cancelled");
        }
    }
    return writer.finish();
}

}  // namespace refocus
