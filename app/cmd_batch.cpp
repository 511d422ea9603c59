// refocus batch plan|run|status <shots.json>: many shots from one shot list, on this machine.
// Each shot is its own sequence of `refocus` commands (new, fit, export) run as child processes,
// so that a shot that fails or is killed leaves its project as a plain fit would, and running
// the list again finishes it: what is done is skipped (docs/method.md, Batches).
#include <sys/resource.h>
#include <sys/wait.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>
#include <tuple>

#include "args.h"
#include "batch.h"
#include "commands.h"
#include "fit/presets.h"
#include "fit/settings.h"
#include "project/project.h"
#include "session/fit_session.h"
#include "util/error.h"
#include "util/json_file.h"

namespace refocus {
namespace batch {
namespace {

std::string fmt(const char* f, double v) {
    char b[64];
    std::snprintf(b, sizeof b, f, v);
    return b;
}

// A path of the shot list, relative to the list's folder unless absolute.
std::string beside(const fs::path& list, const std::string& p) {
    if (p.empty() || fs::path(p).is_absolute()) return p;
    return (list.parent_path() / p).lexically_normal().string();
}

// One CSV record's fields (RFC 4180 quoting: "a, b" and "" inside quotes).
std::vector<std::string> csv_fields(const std::string& line) {
    std::vector<std::string> out(1);
    bool quoted = false;
    for (size_t i = 0; i < line.size(); ++i) {
        const char c = line[i];
        if (quoted && c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
            out.back() += '"', ++i;
        } else if (c == '"') {
            quoted = !quoted;
        } else if (c == ',' && !quoted) {
            out.emplace_back();
        } else if (c != '\r') {
            out.back() += c;
        }
    }
    return out;
}

// A CSV shot list as the JSON one: a header of field names, a row a shot; "set" holds
// name=value pairs and "exports" what:format:out triples, each separated by ';'.
nlohmann::json csv_shots(const fs::path& list) {
    std::ifstream f(list);
    if (!f) throw Error(file_error(list.string(), "cannot be read"));
    std::string line;
    std::vector<std::string> head;
    nlohmann::json shots = nlohmann::json::array();
    auto split = [](const std::string& v, char sep) {
        std::vector<std::string> out;
        size_t a = 0;
        for (size_t b; (b = v.find(sep, a)) != std::string::npos; a = b + 1)
            out.push_back(v.substr(a, b - a));
        out.push_back(v.substr(a));
        return out;
    };
    for (int n = 1; std::getline(f, line); ++n) {
        if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
        const auto v = csv_fields(line);
        if (head.empty()) {
            head = v;
            continue;
        }
        const std::string at = "line " + std::to_string(n);
        if (v.size() != head.size())
            throw Error(file_error(list.string(), at + " has " + std::to_string(v.size()) +
                                                      " fields, the header " +
                                                      std::to_string(head.size())));
        nlohmann::json shot = nlohmann::json::object();
        for (size_t k = 0; k < v.size(); ++k) {
            if (v[k].empty()) continue;
            const std::string& key = head[k];
            if (key == "minutes" || key == "iters" || key == "window" || key == "overlap") {
                try {
                    size_t used = 0;
                    const double x = std::stod(v[k], &used);
                    if (used != v[k].size()) throw std::invalid_argument(v[k]);
                    if (key != "minutes" && x == std::floor(x) && std::abs(x) < 1e15)
                        shot[key] = (long long)x;
                    else
                        shot[key] = x;
                } catch (const std::exception&) {
                    shot[key] = v[k];  // refused below, naming the shot and the field
                }
            } else if (key == "set") {
                shot[key] = nlohmann::json::object();
                for (const auto& a : split(v[k], ';')) {
                    const auto eq = a.find('=');
                    if (eq == std::string::npos)
                        throw Error(file_error(
                            list.string(), at + ": \"set\" entries are name=value ('" + a + "')"));
                    shot[key][a.substr(0, eq)] = a.substr(eq + 1);
                }
            } else if (key == "exports") {
                shot[key] = nlohmann::json::array();
                for (const auto& e : split(v[k], ';')) {
                    const auto t = split(e, ':');
                    if (t.size() != 3)
                        throw Error(file_error(
                            list.string(),
                            at + ": \"exports\" entries are what:format:out ('" + e + "')"));
                    shot[key].push_back({{"what", t[0]}, {"format", t[1]}, {"out", t[2]}});
                }
            } else {
                shot[key] = v[k];
            }
        }
        shots.push_back(shot);
    }
    return {{"shots", shots}};
}

}  // namespace

std::vector<Shot> read_shots(const fs::path& list) {
    const nlohmann::json j =
        list.extension() == ".csv" ? csv_shots(list) : read_json_file(list.string());
    const std::string L = list.string();
    auto err = [&](int row, const std::string& name, const std::string& field,
                   const std::string& what) {
        return Error(file_error(L, "shot " + std::to_string(row) +
                                       (name.empty() ? "" : " (" + name + ")") + ": \"" + field +
                                       "\" " + what));
    };
    if (!j.is_object() || !j.contains("shots") || !j["shots"].is_array() || j["shots"].empty())
        throw Error(file_error(L,
                               "a shot list is {\"shots\": [ {\"clip\": ..., \"project\": "
                               "...}, ... ]} with at least one shot"));
    std::vector<Shot> shots;
    static const char* known[] = {"name", "clip", "project", "preset",  "minutes", "iters",
                                  "coc",  "mask", "set",     "exports", "window",  "overlap"};
    for (const auto& r : j["shots"]) {
        Shot s;
        s.row = int(shots.size()) + 1;
        if (!r.is_object()) throw err(s.row, "", "shot", "must be an object");
        for (auto it = r.begin(); it != r.end(); ++it)
            if (std::find(std::begin(known), std::end(known), it.key()) == std::end(known))
                throw err(s.row, "", it.key(),
                          "is not a field of a shot (name, clip, project, preset, minutes, "
                          "iters, coc, mask, set, exports, window, overlap)");
        auto str = [&](const char* f, bool required) {
            if (!r.contains(f)) {
                if (required) throw err(s.row, s.name, f, "is missing");
                return std::string();
            }
            if (!r[f].is_string() || r[f].get<std::string>().empty())
                throw err(s.row, s.name, f, "must be a non-empty string");
            return r[f].get<std::string>();
        };
        s.project = beside(list, str("project", true));
        s.name = r.contains("name") ? str("name", true) : fs::path(s.project).filename().string();
        s.clip = beside(list, str("clip", true));
        s.coc = beside(list, str("coc", false));
        s.mask = beside(list, str("mask", false));
        if (r.contains("preset")) {
            s.preset = str("preset", true);
            try {
                find_preset(s.preset);
            } catch (const std::exception& e) {
                throw err(s.row, s.name, "preset", "is unknown (use " + preset_names(", ") + ")");
            }
        }
        if (r.contains("minutes") && r.contains("iters"))
            throw err(s.row, s.name, "minutes", "and \"iters\" are exclusive: give one budget");
        if (r.contains("minutes")) {
            if (!r["minutes"].is_number() || !(r["minutes"].get<double>() > 0) ||
                r["minutes"].get<double>() > kMaxFitMinutes)
                throw err(s.row, s.name, "minutes",
                          "must be a number in (0, " + fmt("%.0f", kMaxFitMinutes) + "]");
            s.minutes = r["minutes"].get<double>();
        } else if (r.contains("iters")) {
            if (!r["iters"].is_number_integer() || r["iters"].get<long long>() < 1 ||
                r["iters"].get<long long>() > kMaxFitIters)
                throw err(s.row, s.name, "iters",
                          "must be an integer in 1.." + std::to_string(kMaxFitIters));
            s.iters = r["iters"].get<long long>();
        } else {
            s.minutes = 5;
        }
        if (r.contains("set")) {
            if (!r["set"].is_object()) throw err(s.row, s.name, "set", "must be an object");
            Settings check;
            for (auto it = r["set"].begin(); it != r["set"].end(); ++it) {
                const std::string v =
                    it.value().is_string() ? it.value().get<std::string>() : it.value().dump();
                try {
                    check.set(it.key(), v);
                } catch (const std::exception& e) {
                    throw err(s.row, s.name, "set", std::string(": ") + e.what());
                }
                s.set.push_back(it.key() + "=" + v);
            }
        }
        if (r.contains("exports")) {
            if (!r["exports"].is_array()) throw err(s.row, s.name, "exports", "must be an array");
            for (const auto& e : r["exports"]) {
                if (!e.is_object() || !e.contains("what") || !e["what"].is_string() ||
                    !e.contains("out") || !e["out"].is_string())
                    throw err(s.row, s.name, "exports",
                              "entries are {\"what\": ..., \"out\": ..., \"format\": ...}");
                ShotExport x{e["what"].get<std::string>(),
                             e.contains("format") && e["format"].is_string()
                                 ? e["format"].get<std::string>()
                                 : "png",
                             beside(list, e["out"].get<std::string>())};
                if (x.what != "all") try {
                        parse_export_pass(x.what);
                    } catch (const std::exception&) {
                        throw err(s.row, s.name, "exports",
                                  "names an unknown pass '" + x.what + "'");
                    }
                static const char* formats[] = {"png", "exr", "tiff", "mp4"};
                if (std::find(std::begin(formats), std::end(formats), x.format) ==
                    std::end(formats))
                    throw err(s.row, s.name, "exports", "format must be png, exr, tiff or mp4");
                s.exports.push_back(x);
            }
        }
        for (auto [f, v, lo] : {std::tuple<const char*, int*, int>{"window", &s.window, 0},
                                {"overlap", &s.overlap, 1}}) {
            if (!r.contains(f)) continue;
            if (!r[f].is_number_integer() || r[f].get<long long>() < lo ||
                r[f].get<long long>() > 1000000)
                throw err(s.row, s.name, f,
                          "must be an integer in " + std::to_string(lo) + "..1000000");
            *v = r[f].get<int>();
        }
        if (s.window > 0 && s.window < 2 * s.overlap)
            throw err(s.row, s.name, "window",
                      "must be at least twice \"overlap\" (" + std::to_string(s.overlap) +
                          "), or 0 to fit the shot whole");
        if (!fs::exists(s.clip) && s.clip.find('%') == std::string::npos)
            throw err(s.row, s.name, "clip", "does not exist: " + s.clip);
        shots.push_back(s);
    }
    // Two shots may not share a project or an output.
    for (size_t a = 0; a < shots.size(); ++a)
        for (size_t b = 0; b < a; ++b) {
            if (fs::absolute(shots[a].project) == fs::absolute(shots[b].project))
                throw err(shots[a].row, shots[a].name, "project",
                          "is shot " + std::to_string(shots[b].row) + "'s project too");
            for (const auto& x : shots[a].exports)
                for (const auto& y : shots[b].exports)
                    if (fs::absolute(x.out) == fs::absolute(y.out))
                        throw err(shots[a].row, shots[a].name, "exports",
                                  "writes " + x.out + ", as shot " + std::to_string(shots[b].row) +
                                      " does");
        }
    return shots;
}

const ClipInfo& clip_info_of(const Shot& s) {
    if (!s.clip_info) s.clip_info = std::make_shared<ClipInfo>(ClipReader::open(s.clip)->info());
    return *s.clip_info;
}

const std::vector<ShotWindow>& windows_of(const Shot& s) {
    if (s.windows) return *s.windows;
    auto w = std::make_shared<std::vector<ShotWindow>>();
    const fs::path dir = s.project;
    const std::string at = "shot " + std::to_string(s.row) + " (" + s.name + ")";
    if (s.last >= 0 || fs::exists(dir / Project::kFileName)) {
        // a window, or a shot already ingested whole
    } else if (fs::exists(dir / WindowedShot::kFileName)) {
        const WindowedShot ws = WindowedShot::load(dir);
        if (ws.window != s.window || ws.overlap != s.overlap)
            throw Error(file_error((dir / WindowedShot::kFileName).string(),
                                   at + " was split into windows of " + std::to_string(ws.window) +
                                       " frames overlapping by " + std::to_string(ws.overlap) +
                                       "; the list now says " + std::to_string(s.window) + " and " +
                                       std::to_string(s.overlap) +
                                       " (keep them, or remove the shot's project)"));
        *w = ws.windows;
    } else if (s.window > 0) {
        const int frames = clip_info_of(s).frames;
        if (frames > s.window) {
            if (!s.coc.empty() || !s.mask.empty())
                throw Error(at + ": " + std::to_string(frames) + " frames, over its window of " +
                            std::to_string(s.window) +
                            ", and --coc/--mask files count from the clip's first frame: fit it "
                            "whole (\"window\": 0)");
            *w = plan_windows(frames, s.window, s.overlap);
        }
    }
    s.windows = w;
    return *w;
}

std::vector<Shot> window_shots(const Shot& s) {
    std::vector<Shot> out;
    const auto& ws = windows_of(s);
    for (size_t k = 0; k < ws.size(); ++k) {
        Shot w = s;
        w.project = (fs::path(s.project) / ws[k].dir).string();
        w.name = s.name + "_" + fs::path(ws[k].dir).filename().string();
        w.exports.clear();
        w.first = ws[k].first, w.last = ws[k].last;
        w.windows = std::make_shared<std::vector<ShotWindow>>();
        out.push_back(w);
    }
    return out;
}

ShotState state_of(const Shot& s) {
    ShotState st;
    for (const auto& x : s.exports) st.exports_done += fs::exists(x.out);
    if (!windows_of(s).empty()) {  // the windows' states together
        st.project = fs::exists(fs::path(s.project) / WindowedShot::kFileName);
        st.fitted = st.project;
        double reblur = 0;
        int n = 0;
        for (const Shot& w : window_shots(s)) {
            const ShotState ws = state_of(w);
            st.fitted = st.fitted && ws.fitted;
            st.checkpoint = st.checkpoint || ws.checkpoint;
            st.steps += ws.steps;
            if (!std::isnan(ws.reblur)) reblur += ws.reblur, ++n;
        }
        st.reblur = n ? reblur / n : NAN;
        return st;
    }
    if (!fs::exists(fs::path(s.project) / Project::kFileName)) return st;
    st.project = true;
    try {
        const Project p = Project::load(s.project);
        st.checkpoint = fs::exists(fs::path(s.project) / "fit" / "checkpoint.json");
        if (p.sections.contains("fit")) {
            const auto& f = p.sections.at("fit");
            const auto status = f.value("status", nlohmann::json::object());
            st.steps = status.value("step", 0LL);
            st.reblur = status.value("reblur_psnr", NAN);
            const bool same = f.value("preset", std::string()) == s.preset &&
                              std::abs(f.value("minutes", 0.0) - s.minutes) < 1e-9 &&
                              f.value("iters", 0LL) == s.iters;
            st.fitted = same && status.value("state", std::string()) == "done";
            st.resumable = same && !st.fitted && st.checkpoint;
        }
    } catch (const std::exception&) {
        st.project = false;  // run says why
    }
    return st;
}

std::vector<std::vector<std::string>> steps_of(const Shot& s, const ShotState& st) {
    std::vector<std::vector<std::string>> out;
    if (!windows_of(s).empty()) {
        for (const Shot& w : window_shots(s)) {
            const auto more = steps_of(w, state_of(w));
            out.insert(out.end(), more.begin(), more.end());
        }
    } else {
        if (!st.project) {
            out.push_back({"new", s.clip, "-o", s.project});
            if (s.last >= 0)
                out.back().insert(out.back().end(), {"--first", std::to_string(s.first), "--last",
                                                     std::to_string(s.last)});
        }
        if (!st.fitted) {
            std::vector<std::string> fit = {"fit", s.project, "--preset", s.preset};
            if (s.iters > 0)
                fit.insert(fit.end(), {"--iters", std::to_string(s.iters)});
            else
                fit.insert(fit.end(), {"--minutes", fmt("%.17g", s.minutes)});
            if (!s.coc.empty()) fit.insert(fit.end(), {"--coc", s.coc});
            if (!s.mask.empty()) fit.insert(fit.end(), {"--mask", s.mask});
            for (const auto& a : s.set) fit.insert(fit.end(), {"--set", a});
            if (st.resumable) fit.push_back("--resume");
            out.push_back(fit);
        }
    }
    for (const auto& x : s.exports)
        if (!st.fitted || !fs::exists(x.out))
            out.push_back(
                {"export", s.project, "--what", x.what, "--format", x.format, "--out", x.out});
    return out;
}

namespace {

// Runs `refocus <args>` with its output appended to `log`; the exit code, and the child's peak
// resident memory (KiB) in `peak_kb`.
int run_child(const std::vector<std::string>& args, const fs::path& log, int threads,
              long* peak_kb) {
    std::vector<std::string> argv = {"/proc/self/exe"};
    argv.insert(argv.end(), args.begin(), args.end());
    const pid_t pid = fork();
    if (pid < 0) throw Error("batch: cannot start a process: " + std::string(strerror(errno)));
    if (pid == 0) {
        const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
        if (fd >= 0) dup2(fd, 1), dup2(fd, 2);
        setenv("REFOCUS_THREADS", std::to_string(threads).c_str(), 1);
        std::vector<char*> c;
        for (auto& a : argv) c.push_back(a.data());
        c.push_back(nullptr);
        execv("/proc/self/exe", c.data());
        _exit(127);
    }
    int status = 0;
    struct rusage ru {};
    while (wait4(pid, &status, 0, &ru) < 0 && errno == EINTR) {
    }
    *peak_kb = std::max(*peak_kb, long(ru.ru_maxrss));
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

void print_table(const std::vector<Shot>& shots, const std::vector<Outcome>* outcomes,
                 const std::vector<std::string>& slurm) {
    const bool with_slurm =
        std::any_of(slurm.begin(), slurm.end(), [](const std::string& x) { return !x.empty(); });
    std::printf("%-16s %-10s %7s %8s %8s %9s  %s%s\n", "shot", "state", "steps", "reblur", "time s",
                "peak MB", with_slurm ? "slurm                   " : "", "outputs");
    for (size_t i = 0; i < shots.size(); ++i) {
        const Shot& s = shots[i];
        const ShotState st = state_of(s);
        const std::string state = outcomes ? (*outcomes)[i].state : project_state(s);
        std::string sl;
        if (with_slurm) {
            sl = slurm[i].empty() ? "-" : slurm[i];
            sl.resize(std::max<size_t>(sl.size() + 1, 24), ' ');
        }
        std::printf("%-16s %-10s %7lld %8s %8s %9s  %s%d/%zu %s\n", s.name.c_str(), state.c_str(),
                    st.steps, std::isnan(st.reblur) ? "-" : fmt("%.2f", st.reblur).c_str(),
                    outcomes ? fmt("%.1f", (*outcomes)[i].seconds).c_str() : "-",
                    outcomes && (*outcomes)[i].peak_kb > 0
                        ? fmt("%.0f", (*outcomes)[i].peak_kb / 1024.0).c_str()
                        : "-",
                    sl.c_str(), st.exports_done, s.exports.size(), s.project.c_str());
    }
}

int batch_run(const fs::path& list, const std::vector<Shot>& shots, int jobs) {
    const fs::path logs = logs_folder(list);
    fs::create_directories(logs);
    const int cores = std::max(1u, std::thread::hardware_concurrency());
    const int threads = std::max(1, cores / jobs);
    std::vector<Outcome> out(shots.size());
    std::atomic<size_t> next{0};
    std::mutex print;
    auto worker = [&] {
        for (size_t i; (i = next++) < shots.size();) {
            try {
                out[i] = run_shot(shots[i], logs, threads, print, nullptr);
            } catch (const std::exception& e) {
                out[i].state = "failed";
                std::lock_guard<std::mutex> l(print);
                std::printf("[%s] failed: %s\n", shots[i].name.c_str(), e.what());
            }
        }
    };
    std::vector<std::thread> pool;
    for (int k = 0; k < std::min<int>(jobs, int(shots.size())); ++k) pool.emplace_back(worker);
    for (auto& t : pool) t.join();
    std::printf("\n");
    print_table(shots, &out, {});
    const auto failed =
        std::count_if(out.begin(), out.end(), [](const Outcome& o) { return o.state == "failed"; });
    return failed ? 1 : 0;
}

}  // namespace

std::string joined(const std::vector<std::string>& v) {
    std::string s;
    for (const auto& a : v) s += (s.empty() ? "" : " ") + a;
    return s;
}

std::string project_state(const Shot& s) {
    const ShotState st = state_of(s);
    return st.fitted && st.exports_done == int(s.exports.size()) ? "done"
           : st.fitted                                           ? "fitted"
           : st.checkpoint                                       ? "partial"
           : st.project                                          ? "ingested"
                                                                 : "to do";
}

Outcome run_shot(const Shot& s, const fs::path& logs, int threads, std::mutex& print,
                 const volatile std::sig_atomic_t* stop, int window) {
    Outcome out;
    const auto t0 = std::chrono::steady_clock::now();
    const auto& ws = windows_of(s);
    if (!ws.empty() && !fs::exists(fs::path(s.project) / WindowedShot::kFileName)) {
        WindowedShot shot;  // the shot's folder: its windows, before any of them is made
        shot.dir = s.project;
        shot.clip = fs::absolute(s.clip).string();
        shot.frames = ws.back().last + 1;
        shot.window = s.window, shot.overlap = s.overlap;
        shot.windows = ws;
        fs::create_directories(shot.dir);
        shot.save();
    }
    if (window >= int(ws.size()))
        throw Error("shot " + s.name + " has " + std::to_string(ws.size()) + " windows, not " +
                    std::to_string(window + 1));
    const Shot unit = window >= 0 ? window_shots(s)[size_t(window)] : s;
    const auto steps = steps_of(unit, state_of(unit));
    const fs::path log = logs / (unit.name + ".log");
    out.state = steps.empty() ? "skipped" : "done";
    for (const auto& step : steps) {
        if (stop && *stop) {
            out.state = "stopped";
            break;
        }
        {
            std::lock_guard<std::mutex> l(print);
            std::printf("[%s] %s\n", unit.name.c_str(), joined(step).c_str());
            std::fflush(stdout);
        }
        if (step[0] == "export") {  // an output's folder, as a person would make it
            std::error_code ec;
            fs::create_directories(fs::path(step.back()).parent_path(), ec);
        }
        const int rc = run_child(step, log, threads, &out.peak_kb);
        if (rc != 0) {
            out.state = stop && *stop ? "stopped" : "failed";
            std::lock_guard<std::mutex> l(print);
            std::printf("[%s] %s %s (exit %d): see %s\n", unit.name.c_str(), step[0].c_str(),
                        out.state.c_str(), rc, log.string().c_str());
            break;
        }
    }
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::lock_guard<std::mutex> l(print);
    std::printf("[%s] %s in %.1f s\n", unit.name.c_str(), out.state.c_str(), out.seconds);
    std::fflush(stdout);
    return out;
}

}  // namespace batch

int cmd_batch(int argc, char** argv) {
    using namespace batch;
    static const char* usage =
        "usage: refocus batch plan|run|status|submit <shots.json|.csv> [--jobs N] "
        "[--partition P] [--account A] [--cpus N] [--time MIN] [--mem MB] [--dry-run]";
    if (argc < 4) throw Error(usage);
    const std::string verb = argv[2];
    const fs::path list = fs::absolute(argv[3]);
    if (verb == "submit" || verb == "shot") {
        const std::vector<Shot> shots = read_shots(list);
        return verb == "submit" ? batch_submit(list, shots, argc, argv)
                                : batch_shot(list, shots, argc, argv);
    }
    Args a(argc, argv, 2);
    a.check_known({"jobs"});
    const auto& pos = a.positional();
    if (pos.size() != 2 || (pos[0] != "plan" && pos[0] != "run" && pos[0] != "status"))
        throw Error(usage);
    const std::vector<Shot> shots = read_shots(list);
    if (pos[0] == "status") {
        print_table(shots, nullptr, slurm_states(list, shots));
        return 0;
    }
    if (pos[0] == "plan") {
        for (const Shot& s : shots) {
            const auto steps = steps_of(s, state_of(s));
            std::string windows;
            for (const auto& w : windows_of(s))
                windows += (windows.empty() ? "in windows of frames " : ", ") +
                           std::to_string(w.first) + ".." + std::to_string(w.last);
            std::printf("shot %d %s: %s%s\n", s.row, s.name.c_str(),
                        steps.empty() ? "done, skipped" : "", windows.c_str());
            for (const auto& st : steps) std::printf("  refocus %s\n", joined(st).c_str());
        }
        return 0;
    }
    const double jobs = a.get_double("jobs", 1);
    if (!(jobs >= 1 && jobs <= 256) || jobs != std::floor(jobs))
        throw Error("--jobs must be an integer in 1..256 (got " + a.get("jobs") + ")");
    return batch_run(list, shots, int(jobs));
}

}  // namespace refocus
