// refocus bench scale: what a fit costs as the frame grows. One synth scene rendered at several
// sizes; for each, the ingest and preparation times, the time a step takes on whole frames and
// on crops (docs/method.md, Crops), the training time each takes to reach the input's sharp
// PSNR + 3 dB with the true radius, and each run's peak resident memory. Every (size, mode) runs
// in a child process of its own, so that its peak (VmHWM) is its own.
#include <unistd.h>

#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include "args.h"
#include "commands.h"
#include "fit/fit_engine.h"
#include "fit/fit_setup.h"
#include "io/clip.h"
#include "io/tensor_image.h"
#include "metrics/metrics.h"
#include "project/project.h"
#include "session/fit_session.h"
#include "util/error.h"
#include "util/process.h"

namespace refocus {

namespace {

using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// The process's peak resident memory (VmHWM), MiB; -1 when /proc does not say.
double peak_rss_mib() {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;  // kB
    return -1;
}

// Mean sharp PSNR (sRGB 8-bit, as bench fit scores) of the model's frames, rendered a few at a
// time so that each composes the atlases once.
double sharp_psnr(FitEngine& e, const std::vector<Image>& gt) {
    std::vector<Image> out;
    const int T = int(gt.size());
    for (int t0 = 0; t0 < T; t0 += 6) {
        std::vector<int64_t> frames;
        for (int t = t0; t < std::min(T, t0 + 6); ++t) frames.push_back(t);
        torch::NoGradGuard g;
        std::lock_guard<std::mutex> lock(e.model_mutex());
        Layers L = e.model().render(frames);
        for (size_t b = 0; b < frames.size(); ++b)
            out.push_back(tensor_to_image(L.sharp[int64_t(b)].clamp_min(0)));
    }
    return mean_psnr(out, gt);
}

// One (size, mode) in its own process: ingest and prepare when the project is not there yet,
// then fit until the sharp PSNR reaches the input's + 3 dB or the time runs out. Prints one
// line "RESULT key=value ...".
int scale_child(const Args& a) {
    const fs::path clip = a.get("clip"), work = a.get("project");
    const std::string mode = a.get("child");
    std::map<std::string, double> r;
    Project project;
    const bool fresh = !fs::exists(work / "project.json");  // the first run ingests and prepares
    if (fresh) {
        const auto t0 = Clock::now();
        project = create_project((clip / "input_%04d.png").string(), work, {});
        r["ingest_s"] = since(t0);
    } else {
        project = Project::load(work);
    }
    FitSettings s;
    Settings settings;
    for (const auto& assignment : a.get_all("set")) settings.set_assignment(assignment);
    settings.set("fit.crop_px", mode == "whole" ? "0" : a.get("crop-px", "320"));
    use_settings(s, settings);
    s.setup.coc_path = (clip / "coc_%04d.exr").string();
    s.fit.minutes = a.get_double("max-minutes", 10.0);
    PrepareLog log;
    auto t0 = Clock::now();
    auto data = build_fit_data(project, s.setup, log);
    if (fresh) r["prepare_s"] = since(t0);
    const auto gt = read_all_frames((clip / "sharp_%04d.png").string());
    std::vector<Image> input;
    for (int t = 0; t < project.frames; ++t) input.push_back(project.read_frame(t));
    const double in_psnr = mean_psnr(input, gt), goal = in_psnr + a.get_double("goal-db", 3.0);
    FitEngine engine(data, s.fit);
    r["input_db"] = in_psnr;
    r["reached_min"] = -1;
    double last_eval = 0, psnr = 0;
    while (!engine.done()) {
        engine.step();
        const double el = engine.snapshot().elapsed_s;
        // Often early (the goal may come within seconds), every 30 s of training later.
        if (el - last_eval < std::min(30.0, std::max(2.0, 0.15 * el)) && !engine.done()) continue;
        last_eval = el;
        psnr = sharp_psnr(engine, gt);
        if (!r.count("first_db")) r["first_db"] = psnr;
        std::printf("  %s: step %lld, %.2f min, %.2f dB\n", mode.c_str(),
                    (long long)engine.snapshot().step, el / 60, psnr);
        std::fflush(stdout);
        if (psnr >= goal) {
            r["reached_min"] = el / 60.0;
            break;
        }
    }
    const FitSnapshot snap = engine.snapshot();
    r["steps"] = double(snap.step);
    r["step_s"] = snap.elapsed_s / std::max<int64_t>(1, snap.step);
    r["psnr_db"] = psnr;
    r["rss_mib"] = peak_rss_mib();
    std::printf("RESULT");
    for (const auto& [k, v] : r) std::printf(" %s=%.6g", k.c_str(), v);
    std::printf("\n");
    return 0;
}

std::map<std::string, double> parse_result(const std::string& output) {
    std::map<std::string, double> r;
    const size_t at = output.rfind("RESULT");
    if (at == std::string::npos) return r;
    std::istringstream in(output.substr(at + 6, output.find('\n', at) - at - 6));
    std::string kv;
    while (in >> kv) {
        const size_t eq = kv.find('=');
        if (eq != std::string::npos) r[kv.substr(0, eq)] = std::stod(kv.substr(eq + 1));
    }
    return r;
}

std::string self_exe() {
    char buf[4096];
    const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
    if (n <= 0) throw Error("bench scale: cannot find its own executable (/proc/self/exe)");
    return std::string(buf, size_t(n));
}

// The child's result, or a message naming the child's last line when it failed.
std::map<std::string, double> run_child(const std::vector<std::string>& argv, const fs::path& log) {
    Subprocess p(argv);
    const int rc = p.wait();
    write_file_atomic(log, p.output());
    auto r = parse_result(p.output());
    if (rc != 0 || r.empty())
        throw Error("bench scale: the " + argv[4] + " run failed (exit " + std::to_string(rc) +
                    "): " + p.last_line() + " (log: " + log.string() + ")");
    return r;
}

std::string cell(const std::map<std::string, double>& r, const char* key, const char* fmt) {
    auto it = r.find(key);
    if (it == r.end() || it->second < 0) return "-";
    char b[32];
    std::snprintf(b, sizeof b, fmt, it->second);
    return b;
}

}  // namespace

int bench_scale(int argc, char** argv) {
    Args a(argc, argv, 3);
    a.check_known({"scene", "sizes", "frames", "max-minutes", "work", "crop-px", "set", "child",
                   "clip", "project", "goal-db"});
    if (a.has("child")) return scale_child(a);
    const std::string scene = a.get("scene", "rack");
    const int frames = a.get_int("frames", 30);
    const double minutes = a.get_double("max-minutes", 10.0);
    const std::string crop = a.get("crop-px", "320");
    const std::string goal = a.get("goal-db", "3");
    const fs::path work =
        a.get("work", (fs::temp_directory_path() / "refocus_bench_scale").string());
    std::vector<std::string> sizes;
    {
        std::stringstream ss(a.get("sizes", "320x180,640x360,1280x720,1920x1080"));
        for (std::string s; std::getline(ss, s, ',');) sizes.push_back(s);
    }
    const std::string exe = self_exe();
    std::printf(
        "refocus bench scale: synth %s, %d frames, true radius; goal: the input's sharp PSNR + "
        "%s dB, at most %g min of training a run; crops: fit.crop_px=%s\n",
        scene.c_str(), frames, goal.c_str(), minutes, crop.c_str());
    std::printf("%-10s %7s %7s | %8s %8s %6s | %-13s %-13s | %6s %6s\n", "size", "ingest", "prep",
                "whole", "crop", "ratio", "whole: goal", "crop: goal", "whole", "crop");
    std::printf("%-10s %7s %7s | %8s %8s %6s | %-13s %-13s | %6s %6s\n", "", "s", "s", "s/step",
                "s/step", "", "min/steps", "min/steps", "MiB", "MiB");
    std::fflush(stdout);
    for (const auto& size : sizes) {
        // Clips are kept under `work` and reused: the aperture renderer takes hours at 1080p.
        const fs::path clip = work / (scene + "_" + size + "_" + std::to_string(frames));
        if (!fs::exists(clip / "clip.json")) {
            Subprocess p({exe, "synth", "--scene", scene, "--size", size, "--frames",
                          std::to_string(frames), "-o", clip.string(), "--quiet"});
            if (p.wait() != 0) throw Error("bench scale: synth " + size + ": " + p.last_line());
        }
        const fs::path project = work / ("project_" + size);
        fs::remove_all(project);
        std::map<std::string, std::map<std::string, double>> res;
        int W = 0, H = 0;
        if (std::sscanf(size.c_str(), "%dx%d", &W, &H) != 2 || W < 1 || H < 1)
            throw Error("bench scale: --sizes takes WxH,WxH,... (got '" + size + "')");
        // Frames no larger than the crop train whole in both modes: one run.
        const bool crops_apply = W > std::stoi(crop) || H > std::stoi(crop);
        for (const std::string mode : {"whole", "crop"}) {
            if (mode == "crop" && !crops_apply) {
                res[mode] = res["whole"];
                continue;
            }
            std::vector<std::string> args{exe,
                                          "bench",
                                          "scale",
                                          "--child",
                                          mode,
                                          "--clip",
                                          clip.string(),
                                          "--project",
                                          project.string(),
                                          "--max-minutes",
                                          std::to_string(minutes),
                                          "--crop-px",
                                          crop,
                                          "--goal-db",
                                          goal};
            for (const auto& s : a.get_all("set")) args.insert(args.end(), {"--set", s});
            res[mode] = run_child(args, work / ("log_" + size + "_" + mode + ".txt"));
        }
        auto& w = res["whole"];
        auto& c = res["crop"];
        auto reached = [](std::map<std::string, double>& r) {
            char b[40];
            if (r["reached_min"] >= 0)
                std::snprintf(b, sizeof b, "%.2f/%.0f", r["reached_min"], r["steps"]);
            else  // not within the cap: the gain it reached
                std::snprintf(b, sizeof b, ">%.1f (%+.1fdB)", r["steps"] * r["step_s"] / 60,
                              r["psnr_db"] - r["input_db"]);
            return std::string(b);
        };
        const std::string ratio = crops_apply && w["step_s"] > 0 && c["step_s"] > 0
                                      ? cell({{"x", w["step_s"] / c["step_s"]}}, "x", "%.1fx")
                                      : std::string("-");
        std::printf("%-10s %7s %7s | %8s %8s %6s | %-13s %-13s | %6s %6s\n", size.c_str(),
                    cell(w, "ingest_s", "%.1f").c_str(), cell(w, "prepare_s", "%.1f").c_str(),
                    cell(w, "step_s", "%.2f").c_str(),
                    crops_apply ? cell(c, "step_s", "%.2f").c_str() : "whole", ratio.c_str(),
                    reached(w).c_str(), crops_apply ? reached(c).c_str() : "whole",
                    cell(w, "rss_mib", "%.0f").c_str(),
                    crops_apply ? cell(c, "rss_mib", "%.0f").c_str() : "-");
        std::fflush(stdout);
    }
    std::printf(
        "s/step: training seconds a step (mean over the run); ratio: whole / crop, measured in "
        "the same run; goal: training minutes and steps to the input's sharp PSNR + %s dB (>M: "
        "not within the cap, with the gain reached then); MiB: the run's peak resident memory "
        "(VmHWM, its own process). 'whole': the frames are no larger than the crop. Logs: "
        "%s/log_*.txt\n",
        goal.c_str(), work.string().c_str());
    return 0;
}

}  // namespace refocus
