// refocus batch submit|shot: a shot list as Slurm job arrays. `submit` writes the array's
// script beside the list and hands it to `sbatch`; each array task runs `refocus batch shot`,
// which finishes one shot exactly as `batch run` would (what is done is skipped, a fit that
// stopped resumes from its checkpoint), so a requeued task picks up where it stopped.
// Refocus keeps no queue of its own: Slurm does the scheduling (docs/method.md, Batches).
#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "args.h"
#include "batch.h"
#include "io/clip.h"
#include "project/project.h"
#include "util/error.h"
#include "util/json_file.h"
#include "util/process.h"

namespace refocus::batch {

namespace {

volatile std::sig_atomic_t g_stop = 0;

// The clip's size: from the project when it is ingested, else from the clip's header.
ClipInfo clip_size(const Shot& s) {
    ClipInfo c;
    if (fs::exists(fs::path(s.project) / Project::kFileName)) {
        const Project p = Project::load(s.project);
        c.width = p.width, c.height = p.height, c.frames = p.frames;
        return c;
    }
    return clip_info_of(s);  // read once, with the shot's windows
}

}  // namespace

// A shot's wall time and memory on a 2-core node, from the measured costs in
// docs/benchmarks.md (Speed: 1920×1080×240 and 384×288×30), with a margin. The fit's `--minutes`
// budget already holds its preparation and set-up; an `--iters` budget adds them.
ShotCost shot_cost(const Shot& s, int width, int height, int frames) {
    const double px = double(width) * height, F = frames;
    const double proxy = std::min(px, 640.0 * 360.0);
    const double ingest = 5 + F * px * 1.2e-7;
    const double setup = F * px * 1.3e-6;         // the fast model's set-up (1080p×240: 11 min)
    const double prep = 10 + F * proxy * 3.7e-5;  // flow, masks, radius on the proxy
    const double step = 0.1 + std::min(px, 2.1e6) * 4e-7;  // crops bound a step
    const double fit = s.iters > 0 ? prep + setup + s.iters * step : s.minutes * 60.0;
    double exports = 0;
    for (const auto& x : s.exports)
        exports += (x.what == "all" ? 6 : 1) * (0.5 * setup + F * px * 1.9e-6);
    ShotCost c;
    c.minutes = int(std::ceil((1.5 * (ingest + fit + exports) + 120) / 60.0));
    // The clip's arrays up to fit.memory_mb (512 MB) in memory, twice; frame-sized buffers of
    // the set-up and the export (1080p: 4.6 GB peak measured); a base for LibTorch.
    const double mb = 1024 + 2 * std::min(F * px * 12 / 1048576.0, 512.0) + px * 1200 / 1048576.0;
    c.mem_mb = int(std::ceil(1.25 * mb / 256.0)) * 256;
    return c;
}

namespace {

std::string slurm_time(int minutes) {
    char b[32];
    std::snprintf(b, sizeof b, "%d-%02d:%02d:00", minutes / 1440, minutes / 60 % 24, minutes % 60);
    return b;
}

// Single quotes for bash: the path as it is, whatever it holds.
std::string sh_quote(const std::string& s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

// A task's work: shot `shot` of the list, window `window` of it (-1: the whole shot).
struct Unit {
    int shot, window;
};

fs::path record_of(const fs::path& list) {
    return list.parent_path() / "batch_slurm" / (list.stem().string() + ".json");
}

int positive_int(const Args& a, const char* k, int def, int hi) {
    if (!a.has(k)) return def;
    const double v = a.get_double(k, def);
    if (!(v >= 1 && v <= hi) || v != std::floor(v))
        throw Error(std::string("--") + k + " must be an integer in 1.." + std::to_string(hi) +
                    " (got " + a.get(k) + ")");
    return int(v);
}

// Slurm's job and partition names: no spaces, quotes or shell characters.
void check_slurm_word(const Args& a, const char* k) {
    const std::string v = a.get(k);
    if (v.empty() || v.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                         "0123456789_-.,") != std::string::npos)
        throw Error(std::string("--") + k + " must be a Slurm name (letters, digits, _ - . ,): '" +
                    v + "'");
}

}  // namespace

int batch_submit(const fs::path& list, const std::vector<Shot>& shots, int argc, char** argv) {
    Args a(argc, argv, 2, {"dry-run"});
    a.check_known({"partition", "account", "cpus", "time", "mem", "max-running", "dry-run"});
    if (a.positional().size() != 2)
        throw Error(
            "usage: refocus batch submit <shots.json|.csv> [--partition P] [--account A] "
            "[--cpus N] [--time MIN] [--mem MB] [--max-running K] [--dry-run]");
    const int cpus = positive_int(a, "cpus", 8, 1024);
    for (const char* k : {"partition", "account"})
        if (a.has(k)) check_slurm_word(a, k);

    // The work left, as units (a shot, or one window of a long shot) of two arrays: the fits,
    // then, after all of them, the stitching exports of the shots fitted as windows.
    std::vector<Unit> fits, stitches;
    ShotCost fit_need, stitch_need;
    auto need = [](ShotCost& n, const ShotCost& k) {
        n.minutes = std::max(n.minutes, k.minutes);
        n.mem_mb = std::max(n.mem_mb, k.mem_mb);
    };
    for (size_t i = 0; i < shots.size(); ++i) {
        const Shot& s = shots[i];
        if (steps_of(s, state_of(s)).empty()) continue;
        const ClipInfo c = clip_size(s);
        const auto windows = window_shots(s);
        if (windows.empty()) {
            fits.push_back({int(i), -1});
            need(fit_need, shot_cost(s, c.width, c.height, c.frames));
            continue;
        }
        for (size_t k = 0; k < windows.size(); ++k) {
            if (steps_of(windows[k], state_of(windows[k])).empty()) continue;
            fits.push_back({int(i), int(k)});
            need(fit_need,
                 shot_cost(windows[k], c.width, c.height, windows[k].last - windows[k].first + 1));
        }
        if (!s.exports.empty()) {
            stitches.push_back({int(i), -1});
            Shot exports_only = s;
            exports_only.minutes = 0, exports_only.iters = 0;
            ShotCost k = shot_cost(exports_only, c.width, c.height, c.frames);
            // each window's set-up once more (export opens each fit)
            k.minutes += int(std::ceil(1.5 * 1.3e-6 * c.width * c.height * c.frames / 60.0));
            need(stitch_need, k);
        }
    }
    if (fits.empty() && stitches.empty()) {
        std::printf("batch submit: every shot of %s is done; nothing submitted\n",
                    list.string().c_str());
        return 0;
    }
    for (ShotCost* n : {&fit_need, &stitch_need}) {
        if (a.has("time")) n->minutes = positive_int(a, "time", 0, 525600);
        if (a.has("mem")) n->mem_mb = positive_int(a, "mem", 0, 1 << 24);
    }
    const fs::path dir = list.parent_path() / "batch_slurm";
    const fs::path logs = logs_folder(list);
    const std::string exe = fs::canonical("/proc/self/exe").string();
    const std::string max_running =
        a.has("max-running") ? "%" + std::to_string(positive_int(a, "max-running", 1, 100000)) : "";

    auto script_of = [&](const std::vector<Unit>& units, const ShotCost& n,
                         const std::string& after, const char* what) {
        std::ostringstream sh;
        sh << "#!/bin/bash\n"
           << "# Written by `refocus batch submit " << list.filename().string() << "`: " << what
           << ".\n"
           << "#SBATCH --job-name=refocus-" << list.stem().string() << "\n"
           << "#SBATCH --array=0-" << units.size() - 1 << max_running << "\n"
           << "#SBATCH --cpus-per-task=" << cpus << "\n"
           << "#SBATCH --mem=" << n.mem_mb << "M\n"
           << "#SBATCH --time=" << slurm_time(n.minutes) << "\n"
           << "#SBATCH --requeue\n"
           << "#SBATCH --open-mode=append\n"
           << "#SBATCH --output=" << (logs / "slurm_%A_%a.log").string() << "\n";
        if (!after.empty()) sh << "#SBATCH --dependency=afterok:" << after << "\n";
        if (a.has("partition")) sh << "#SBATCH --partition=" << a.get("partition") << "\n";
        if (a.has("account")) sh << "#SBATCH --account=" << a.get("account") << "\n";
        sh << "# Task t runs shot units[t] (its index in the list, and its window; -1: the whole "
              "shot)\nunits=(";
        for (const Unit& u : units) sh << " " << u.shot << ":" << u.window;
        sh << " )\nIFS=: read -r shot window <<< \"${units[$SLURM_ARRAY_TASK_ID]}\"\n"
           << "exec " << sh_quote(exe) << " batch shot " << sh_quote(list.string())
           << " --index \"$shot\" --window \"$window\" --threads \"${SLURM_CPUS_PER_TASK:-" << cpus
           << "}\"\n";
        return sh.str();
    };
    auto describe = [&](const std::vector<Unit>& units, const ShotCost& n, const char* what) {
        std::printf("batch submit: %s: %zu task%s, each %d core%s, %d MB and %s (the largest)\n",
                    what, units.size(), units.size() == 1 ? "" : "s", cpus, cpus == 1 ? "" : "s",
                    n.mem_mb, slurm_time(n.minutes).c_str());
    };
    auto sbatch = [&](const fs::path& script, const std::string& text) {
        write_file_atomic(script, text);
        Subprocess sb({"sbatch", "--parsable", script.string()});
        const int rc = sb.wait();
        if (rc != 0)
            throw Error("batch submit: sbatch failed (exit " + std::to_string(rc) +
                        "): " + sb.last_line() + " (the script is " + script.string() + ")");
        const std::string job = sb.last_line();
        return job.substr(0, job.find(';'));  // "id;cluster" on a federation
    };
    const bool dry = a.has("dry-run");
    if (!dry) fs::create_directories(dir), fs::create_directories(logs);
    nlohmann::json rec = {{"arrays", nlohmann::json::array()}};
    std::string fit_job = dry ? "<fits>" : "";
    auto record = [&](const std::string& job, const std::vector<Unit>& units) {
        nlohmann::json u = nlohmann::json::array();
        for (const Unit& x : units) u.push_back({x.shot, x.window, shots[x.shot].name});
        rec["arrays"].push_back({{"job", job}, {"units", u}});
    };
    if (!fits.empty()) {
        describe(fits, fit_need, "fits");
        const std::string text =
            script_of(fits, fit_need, "", "the fits, one task a shot or window");
        if (dry) {
            std::printf("%s", text.c_str());
        } else {
            fit_job = sbatch(dir / (list.stem().string() + ".sbatch"), text);
            record(fit_job, fits);
            std::printf("submitted job array %s\n", fit_job.c_str());
        }
    }
    if (!stitches.empty()) {
        describe(stitches, stitch_need, "exports of the shots fitted as windows");
        const std::string text =
            script_of(stitches, stitch_need, fits.empty() ? "" : fit_job,
                      "the exports of the shots fitted as windows, after every fit");
        if (dry) {
            std::printf("%s", text.c_str());
        } else {
            const std::string job = sbatch(dir / (list.stem().string() + "_exports.sbatch"), text);
            record(job, stitches);
            std::printf("submitted job array %s (after %s)\n", job.c_str(),
                        fits.empty() ? "nothing" : fit_job.c_str());
        }
    }
    if (dry) return 0;
    write_file_atomic(record_of(list), rec.dump(2) + "\n");
    std::printf("`refocus batch status %s` follows them\n", list.filename().string().c_str());
    return 0;
}

int batch_shot(const fs::path& list, const std::vector<Shot>& shots, int argc, char** argv) {
    Args a(argc, argv, 2);
    a.check_known({"index", "threads", "window"});
    if (a.positional().size() != 2 || !a.has("index"))
        throw Error(
            "usage: refocus batch shot <shots.json|.csv> --index I [--window K] [--threads N] "
            "(an array task of `batch submit`)");
    const double i = a.get_double("index", -1);
    if (!(i >= 0 && i < double(shots.size())) || i != std::floor(i))
        throw Error(file_error(list.string(), "has no shot at index " + a.get("index") + " (" +
                                                  std::to_string(shots.size()) +
                                                  " shots; the list changed since it was "
                                                  "submitted?)"));
    const int threads =
        positive_int(a, "threads", std::max(1u, std::thread::hardware_concurrency()), 4096);
    // Slurm sends SIGTERM to every process of a cancelled, preempted or requeued task: the fit
    // saves a checkpoint and stops, and no further step starts.
    std::signal(SIGTERM, [](int) { g_stop = 1; });
    std::signal(SIGINT, [](int) { g_stop = 1; });
    fs::create_directories(logs_folder(list));
    std::mutex print;
    const int window = a.get_int("window", -1);
    const Outcome o =
        run_shot(shots[size_t(i)], logs_folder(list), threads, print, &g_stop, window);
    return o.state == "done" || o.state == "skipped" ? 0 : 1;
}

namespace {

// What Slurm says of job `job`'s array tasks: in the queue (squeue: state and reason), and out
// of it (sacct, where accounting is kept). False where squeue cannot be run.
bool task_states(const std::string& job, std::map<int, std::string>& queued,
                 std::map<int, std::string>& ended) {
    try {
        Subprocess q({"squeue", "-h", "-r", "-j", job, "-o", "%K %T %r"});
        if (q.wait() != 0) return false;
        std::istringstream lines(q.output());
        for (std::string line; std::getline(lines, line);) {
            std::istringstream w(line);
            std::string idx, state, reason;
            w >> idx >> state;
            std::getline(w, reason);
            if (!reason.empty() && reason[0] == ' ') reason.erase(0, 1);
            try {
                queued[std::stoi(idx)] =
                    state + (reason.empty() || reason == "None" ? "" : " (" + reason + ")");
            } catch (const std::exception&) {
            }
        }
    } catch (const std::exception&) {
        return false;  // no squeue here
    }
    try {
        Subprocess a({"sacct", "-n", "-P", "-X", "-j", job, "-o", "JobID,State"});
        if (a.wait() == 0) {
            std::istringstream lines(a.output());
            for (std::string line; std::getline(lines, line);) {
                const auto us = line.find('_'), bar = line.find('|');
                if (us == std::string::npos || bar == std::string::npos || bar < us) continue;
                try {
                    ended[std::stoi(line.substr(us + 1, bar - us - 1))] = line.substr(bar + 1);
                } catch (const std::exception&) {
                }
            }
        }
    } catch (const std::exception&) {
    }
    return true;
}

}  // namespace

std::vector<std::string> slurm_states(const fs::path& list, const std::vector<Shot>& shots) {
    std::vector<std::string> out(shots.size());
    const fs::path rec_path = record_of(list);
    if (!fs::exists(rec_path)) return out;
    nlohmann::json rec;
    try {
        rec = read_json_file(rec_path.string());
    } catch (const std::exception&) {
        return out;
    }
    // Per shot: its tasks still queued (the first shown, and how many more), else the last
    // task's end.
    std::vector<std::vector<std::string>> queued(shots.size());
    std::vector<std::string> last(shots.size());
    for (const auto& arr : rec.value("arrays", nlohmann::json::array())) {
        const std::string job = arr.value("job", std::string());
        std::map<int, std::string> q, e;
        if (job.empty() || !task_states(job, q, e)) continue;
        const auto units = arr.value("units", nlohmann::json::array());
        for (size_t t = 0; t < units.size(); ++t) {
            const auto& u = units[t];
            if (!u.is_array() || u.size() != 3 || !u[0].is_number_integer()) continue;
            const int i = u[0].get<int>();
            if (i < 0 || i >= int(shots.size()) || u[2] != shots[i].name) continue;
            const std::string task = job + "_" + std::to_string(t) + " ";
            if (q.count(int(t)))
                queued[i].push_back(task + q[int(t)]);
            else
                last[i] = task + (e.count(int(t)) ? e[int(t)] : "left the queue");
        }
    }
    for (size_t i = 0; i < shots.size(); ++i)
        out[i] =
            queued[i].empty()
                ? last[i]
                : queued[i][0] +
                      (queued[i].size() > 1 ? " +" + std::to_string(queued[i].size() - 1) : "");
    return out;
}

}  // namespace refocus::batch
