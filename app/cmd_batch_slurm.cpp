// refocus batch submit|shot: a shot list as one Slurm job array. `submit` writes the array's
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
    return ClipReader::open(s.clip)->info();
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

    // The shots still to do, and the largest time and memory among them (one array, one size).
    std::vector<int> todo;
    ShotCost need;
    for (size_t i = 0; i < shots.size(); ++i) {
        if (steps_of(shots[i], state_of(shots[i])).empty()) continue;
        todo.push_back(int(i));
        const ClipInfo c = clip_size(shots[i]);
        const ShotCost k = shot_cost(shots[i], c.width, c.height, c.frames);
        need.minutes = std::max(need.minutes, k.minutes);
        need.mem_mb = std::max(need.mem_mb, k.mem_mb);
    }
    if (todo.empty()) {
        std::printf("batch submit: every shot of %s is done; nothing submitted\n",
                    list.string().c_str());
        return 0;
    }
    if (a.has("time")) need.minutes = positive_int(a, "time", 0, 525600);
    if (a.has("mem")) need.mem_mb = positive_int(a, "mem", 0, 1 << 24);

    std::string array;
    for (int i : todo) array += (array.empty() ? "" : ",") + std::to_string(i);
    if (a.has("max-running"))
        array += "%" + std::to_string(positive_int(a, "max-running", 1, 100000));
    const fs::path dir = list.parent_path() / "batch_slurm";
    const fs::path logs = logs_folder(list);
    const fs::path script = dir / (list.stem().string() + ".sbatch");
    const std::string exe = fs::canonical("/proc/self/exe").string();

    std::ostringstream sh;
    sh << "#!/bin/bash\n"
       << "# Written by `refocus batch submit " << list.filename().string()
       << "`: one array task a shot (its index in the list).\n"
       << "#SBATCH --job-name=refocus-" << list.stem().string() << "\n"
       << "#SBATCH --array=" << array << "\n"
       << "#SBATCH --cpus-per-task=" << cpus << "\n"
       << "#SBATCH --mem=" << need.mem_mb << "M\n"
       << "#SBATCH --time=" << slurm_time(need.minutes) << "\n"
       << "#SBATCH --requeue\n"
       << "#SBATCH --open-mode=append\n"
       << "#SBATCH --output=" << (logs / "slurm_%A_%a.log").string() << "\n";
    if (a.has("partition")) sh << "#SBATCH --partition=" << a.get("partition") << "\n";
    if (a.has("account")) sh << "#SBATCH --account=" << a.get("account") << "\n";
    sh << "exec " << sh_quote(exe) << " batch shot " << sh_quote(list.string())
       << " --index \"$SLURM_ARRAY_TASK_ID\" --threads \"${SLURM_CPUS_PER_TASK:-" << cpus
       << "}\"\n";

    std::printf(
        "batch submit: %zu of %zu shots, each %d core%s, %d MB and %s (the largest "
        "shot's)\n",
        todo.size(), shots.size(), cpus, cpus == 1 ? "" : "s", need.mem_mb,
        slurm_time(need.minutes).c_str());
    if (a.has("dry-run")) {
        std::printf("%s", sh.str().c_str());
        return 0;
    }
    fs::create_directories(dir);
    fs::create_directories(logs);
    write_file_atomic(script, sh.str());
    Subprocess sb({"sbatch", "--parsable", script.string()});
    const int rc = sb.wait();
    if (rc != 0)
        throw Error("batch submit: sbatch failed (exit " + std::to_string(rc) +
                    "): " + sb.last_line() + " (the script is " + script.string() + ")");
    std::string job = sb.last_line();
    job = job.substr(0, job.find(';'));  // "id;cluster" on a federation
    nlohmann::json rec = {
        {"job", job}, {"script", script.string()}, {"shots", nlohmann::json::array()}};
    for (int i : todo) rec["shots"].push_back({{"index", i}, {"name", shots[i].name}});
    write_file_atomic(record_of(list), rec.dump(2) + "\n");
    std::printf("submitted job array %s (%s); `refocus batch status %s` follows it\n", job.c_str(),
                script.string().c_str(), list.filename().string().c_str());
    return 0;
}

int batch_shot(const fs::path& list, const std::vector<Shot>& shots, int argc, char** argv) {
    Args a(argc, argv, 2);
    a.check_known({"index", "threads"});
    if (a.positional().size() != 2 || !a.has("index"))
        throw Error(
            "usage: refocus batch shot <shots.json|.csv> --index I [--threads N] (an "
            "array task of `batch submit`)");
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
    const Outcome o = run_shot(shots[size_t(i)], logs_folder(list), threads, print, &g_stop);
    return o.state == "done" || o.state == "skipped" ? 0 : 1;
}

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
    const std::string job = rec.value("job", std::string());
    if (job.empty()) return out;
    std::map<int, std::string> by_index;
    try {
        Subprocess q({"squeue", "-h", "-r", "-j", job, "-o", "%K %T %r"});
        if (q.wait() != 0) return out;
        std::istringstream lines(q.output());
        for (std::string line; std::getline(lines, line);) {
            std::istringstream w(line);
            std::string idx, state, reason;
            w >> idx >> state;
            std::getline(w, reason);
            if (!reason.empty() && reason[0] == ' ') reason.erase(0, 1);
            try {
                by_index[std::stoi(idx)] =
                    job + "_" + idx + " " + state +
                    (reason.empty() || reason == "None" ? "" : " (" + reason + ")");
            } catch (const std::exception&) {
            }
        }
    } catch (const std::exception&) {
        return out;  // no squeue here
    }
    // Tasks that left the queue: their end state where accounting is kept.
    std::map<int, std::string> ended;
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
    for (const auto& s : rec.value("shots", nlohmann::json::array())) {
        const int i = s.value("index", -1);
        if (i < 0 || i >= int(shots.size()) || s.value("name", std::string()) != shots[i].name)
            continue;
        const auto it = by_index.find(i);
        const std::string task = job + "_" + std::to_string(i);
        out[i] = it != by_index.end() ? it->second
                 : ended.count(i)     ? task + " " + ended[i]
                                      : task + " left the queue";
    }
    return out;
}

}  // namespace refocus::batch
