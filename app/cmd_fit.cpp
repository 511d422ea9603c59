// refocus fit / refocus export
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdio>

#include "args.h"
#include "commands.h"
#include "progress.h"
#include "prepare/noise.h"
#include "edit/atlas_edit.h"
#include "session/fit_session.h"
#include "session/windows.h"
#include "util/error.h"
#include "util/lock.h"
#include "util/timing.h"
#include "util/validate.h"

namespace refocus {

namespace {

volatile std::sig_atomic_t g_interrupted = 0;

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}
std::string fixed1(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.1f", v);
    return b;
}

// A progress bar on a terminal, plain lines (every ~10 s) when not.
class Progress {
  public:
    void update(const FitSnapshot& s, bool force = false) {
        const bool tty = isatty(fileno(stderr));
        if (!tty && !force && s.elapsed_s - m_last < 10.0) return;
        m_last = s.elapsed_s;
        std::string terms;
        for (const auto& [k, v] : s.terms) {
            char b[48];
            std::snprintf(b, sizeof b, " %s=%.4g", k.c_str(), v);
            terms += b;
        }
        if (tty) {
            const int width = 24, fill = static_cast<int>(s.progress * width);
            std::fprintf(stderr,
                         "\r[%s%s] %3.0f%% step %lld  reblur %.2f dB  elapsed %s  ETA %s   ",
                         std::string(fill, '#').c_str(), std::string(width - fill, ' ').c_str(),
                         100 * s.progress, static_cast<long long>(s.step), s.reblur_psnr,
                         clock_text(s.elapsed_s).c_str(), clock_text(s.eta_s).c_str());
            if (force) std::fprintf(stderr, "\n");
        } else {
            std::fprintf(stderr, "step=%lld elapsed=%.1fs eta=%.0fs reblur_psnr=%.2f loss=%.5f%s\n",
                         static_cast<long long>(s.step), s.elapsed_s, s.eta_s, s.reblur_psnr,
                         s.loss, terms.c_str());
        }
    }

  private:
    double m_last = -1e9;
};

}  // namespace

int cmd_fit(int argc, char** argv) {
    const Clock::time_point started = Clock::now();
    Args a(argc, argv, 2, {"resume", "reprepare", "list-settings"});
    a.check_known({"preset", "minutes", "iters", "coc", "mask", "seed", "resume", "batch",
                   "checkpoint-seconds", "reprepare", "set", "list-settings"});
    if (a.has("list-settings")) {
        std::printf("%s", settings_table().c_str());
        return 0;
    }
    if (a.positional().size() != 1)
        throw Error("usage: refocus fit <project> [--preset " + preset_names() +
                    "] [--minutes M | --iters N] [--coc <pattern>] [--mask <pattern>] [--seed S] "
                    "[--batch N] [--set name=value]... [--resume] | refocus fit --list-settings");
    Project project = Project::load(a.positional()[0]);
    const auto lock = ProjectLock::acquire(project.dir, "refocus fit");
    FitSettings s = read_fit_settings(project);
    const bool resume = a.has("resume");
    // A new fit keeps the project's settings (a resumed one must: its checkpoint was trained
    // with them); --set changes them.
    Settings settings = s.fit.settings;
    if (!resume) s = FitSettings{};
    for (const auto& assignment : a.get_all("set")) settings.set_assignment(assignment);
    use_settings(s, settings);
    s.fit.preset = a.get("preset", s.fit.preset);
    find_preset(s.fit.preset);
    // Each flag is checked against the bound the loader applies to what it stores (project.h).
    if (a.has("minutes") || a.has("iters")) {
        s.fit.minutes = a.has("minutes") ? checked_range("--minutes", a.get_double("minutes", 0), 0,
                                                         kMaxFitMinutes, true)
                                         : 0.0;
        s.fit.iters =
            a.has("iters") ? checked_int("--iters", a.get_double("iters", 0), 1, kMaxFitIters) : 0;
    }
    if (s.fit.minutes <= 0 && s.fit.iters <= 0) s.fit.minutes = 5.0;
    if (s.fit.minutes < 0 || s.fit.iters < 0) throw Error("--minutes and --iters must be positive");
    if (a.has("seed")) s.fit.seed = static_cast<uint64_t>(checked_fit_flag("seed", a.get("seed")));
    if (a.has("batch"))  // frames per step; left out: the model's choice
        s.fit.batch = checked_batch_arg(checked_fit_flag("batch", a.get("batch")));
    if (a.has("checkpoint-seconds"))
        s.fit.checkpoint_seconds =
            checked_range("--checkpoint-seconds", a.get_double("checkpoint-seconds", 60.0), 0, 1e6);
    if (a.has("coc")) s.setup.coc_path = a.get("coc");
    if (a.has("mask")) s.setup.mask_path = a.get("mask");
    s.setup.force_prepare = a.has("reprepare");

    if (resume && !FitEngine::has_checkpoint(fit_dir(project)))
        throw Error(file_error(fit_dir(project).string(),
                               "nothing to resume: no checkpoint (run without --resume)"));
    PrepareLog log([](const std::string& line) { std::fprintf(stderr, "  %s\n", line.c_str()); });
    StageProgress prep("prepare");
    prep.keep_alive(10.0);
    StageClock prep_clock;  // --debug timing: each preparation stage
    log.set_stage_sink([&](const std::string& name, double begin, double) {
        prep_clock.next("prepare: " + name);
        prep.update(begin, name, true);
    });
    auto data = build_fit_data(project, s.setup, log);
    prep_clock.end();
    prep.done("ready");
    const double prep_s = seconds_since(started);
    // The model's set-up (alignment, fused atlases): a line as it starts, then every 10 s.
    std::fprintf(stderr, "set-up: building the %s model over %d frames\n", s.fit.preset.c_str(),
                 project.frames);
    StageProgress setup_bar("set-up");
    setup_bar.keep_alive(10.0);
    // A resumed fit's checkpoint replaces the alignment and the atlases the set-up would make.
    FitEngine engine(data, resume ? restoring_options(project, s.fit) : s.fit);
    setup_bar.done("model ready");
    for (const auto& line : engine.model_notes()) log.info(line);
    const double setup_s = seconds_since(started) - prep_s;
    log.info("set-up: preparation " + fixed1(prep_s) + " s, model " + fixed1(setup_s) + " s");
    if (timing_enabled()) add_timing("prepare (all)", prep_s), add_timing("set-up (all)", setup_s);
    const fs::path dir = fit_dir(project);
    if (resume) {
        engine.load_checkpoint(dir);
        std::fprintf(stderr, "resumed at step %lld (%.1f s of training)\n",
                     static_cast<long long>(engine.snapshot().step), engine.snapshot().elapsed_s);
    } else if (FitEngine::has_checkpoint(dir)) {
        std::fprintf(
            stderr,
            "note: starting over (the previous fit is replaced; use --resume to continue it)\n");
    }
    // The budget is what the user waits for: preparation and set-up count in it, and a second is
    // kept for the last checkpoint (a tenth of the budget is trained at least).
    if (s.fit.minutes > 0) {
        const double spent = seconds_since(started) + 1.0;
        const double train_min = std::max(s.fit.minutes - spent / 60.0, 0.1 * s.fit.minutes);
        engine.set_time_budget(train_min);  // on --resume: the total, as the budget always was
        std::fprintf(stderr,
                     "budget %.2f min: %.0f s went to preparation and set-up; the fit trains %s "
                     "%.0f s\n",
                     s.fit.minutes, spent - 1.0, resume ? "until, in all," : "for",
                     train_min * 60.0);
    }
    // The settings reach project.json with the first checkpoint (they say how to resume it):
    // a fit that fails before one (a full disk) leaves project.json as it was.
    bool settings_written = false;

    std::signal(SIGINT, [](int) { g_interrupted = 1; });
    std::signal(SIGTERM, [](int) { g_interrupted = 1; });
    Progress bar;
    std::fprintf(stderr, "fitting %s: preset %s, budget %s\n", project.name.c_str(),
                 s.fit.preset.c_str(),
                 s.fit.iters > 0 ? (std::to_string(s.fit.iters) + " steps").c_str()
                                 : (std::to_string(s.fit.minutes) + " min").c_str());
    while (!engine.done()) {
        engine.step();
        if (g_interrupted) engine.request_stop();
        bar.update(engine.snapshot());
        if (engine.maybe_checkpoint(dir) && !settings_written) {
            write_fit_settings(project, s, nullptr);
            settings_written = true;
        }
    }
    engine.save_checkpoint(dir);
    FitSnapshot snap = engine.snapshot();
    bar.update(snap, true);
    write_fit_settings(project, s, &snap);
    std::printf("fit %s: %lld steps in %.1f s, reblur PSNR %.2f dB; checkpoint %s\n",
                snap.status.c_str(), static_cast<long long>(snap.step), snap.elapsed_s,
                snap.reblur_psnr, (dir / "checkpoint.json").string().c_str());
    if (timing_enabled()) std::fprintf(stderr, "%s", timing_table().c_str());
    return g_interrupted ? 130 : 0;
}

// A long shot fitted as windows (session/windows.h): each pass stitched from the windows.
static int export_shot(const Args& a, const std::string& what, const std::string& out) {
    if (a.has("first") || a.has("last"))
        throw Error(
            "--first/--last: a shot's windows are exported whole; export a range from a "
            "window's project");
    const WindowedShot shot = WindowedShot::load(a.positional()[0]);
    std::vector<ExportPass> passes;
    if (what == "all") {
        passes = {ExportPass::Sharp,      ExportPass::Reblur,  ExportPass::Alpha,
                  ExportPass::Coc,        ExportPass::Refocus, ExportPass::Depth,
                  ExportPass::Confidence, ExportPass::Flow};
    } else {
        passes = {parse_export_pass(what)};
    }
    std::printf("shot %s: %d frames in %zu windows (overlap %d)\n", shot.dir.string().c_str(),
                shot.frames, shot.windows.size(), shot.overlap);
    for (ExportPass p : passes) {
        const bool data_pass = is_data_pass(p);
        std::string format = a.get("format", data_pass ? "exr" : "png");
        if (what == "all" && data_pass) format = "exr";
        std::string target = out;
        if (what == "all") {
            target = (fs::path(out) / export_pass_name(p)).string();
            if (format == "mp4") target += ".mp4";
        }
        StageProgress bar(std::string("export ") + export_pass_name(p));
        const auto files = export_windowed(shot, p, format, target, [&](int done, int total) {
            bar.update(total > 0 ? double(done) / total : 0.0,
                       "frame " + std::to_string(done) + "/" + std::to_string(total));
            return true;
        });
        bar.done(std::to_string(files.size()) + " file(s)");
        std::printf("%s: %zu file(s) in %s\n", export_pass_name(p), files.size(), target.c_str());
    }
    return 0;
}

int cmd_export(int argc, char** argv) {
    Args a(argc, argv, 2);
    a.check_known({"what", "format", "out", "first", "last"});
    if (a.positional().size() != 1 || !a.has("out"))
        throw Error(
            "usage: refocus export <project> --what "
            "sharp|reblur|atlas|alpha|coc|uv|refocus|depth|confidence|flow|parallax|all "
            "[--format png|exr|tiff|mp4] [--first N] [--last N] --out <dir-or-file>");
    const std::string what = a.get("what", "sharp");
    const std::string out = a.get("out");
    if (WindowedShot::is_windowed(a.positional()[0])) return export_shot(a, what, out);
    Project project = Project::load(a.positional()[0]);
    if (what == "all" && (fs::path(out).extension() == ".mp4" || fs::is_regular_file(out)))
        throw Error(file_error(out,
                               "--what all writes a folder (one sequence or mp4 per pass): "
                               "give --out a folder"));
    if (what != "all") parse_export_pass(what);  // an unknown pass is refused before the work
    check_export_target(project, out);           // before the (slow) opening of the fit
    if (project.sections.contains("noise"))
        std::printf("noise: %s\n", project_noise(project).describe().c_str());
    PrepareLog log;
    StageProgress opening("opening the fit");
    opening.keep_alive(10.0);
    StageClock open_clock;  // --debug timing
    open_clock.next("export: open the fit");
    auto engine = open_fitted(project, log);
    open_clock.end();
    opening.done("ready");
    const ProjectEdits edits = ProjectEdits::load(project);  // atlas edits follow every frame
    if (edits.has_edits()) std::fprintf(stderr, "applying the project's atlas edits\n");
    std::vector<ExportPass> passes;
    if (what == "all") {
        passes = {ExportPass::Sharp,   ExportPass::Reblur, ExportPass::Atlas,
                  ExportPass::Alpha,   ExportPass::Coc,    ExportPass::Uv,
                  ExportPass::Refocus, ExportPass::Depth,  ExportPass::Confidence,
                  ExportPass::Flow};
        // The parallax field where the fit has one (a moving camera's plane + parallax).
        std::lock_guard<std::mutex> lock(engine->model_mutex());
        if (engine->has_atlas() && engine->model().parallax_bg().defined())
            passes.push_back(ExportPass::Parallax);
    } else {
        passes = {parse_export_pass(what)};
    }
    for (ExportPass p : passes) {
        const bool data_pass = is_data_pass(p);
        std::string format = a.get("format", data_pass ? "exr" : "png");
        if (what == "all" && data_pass) format = "exr";
        if (what == "all" && p == ExportPass::Atlas && format == "mp4") format = "png";
        if (p == ExportPass::Parallax && (what == "all" || !a.has("format"))) format = "exr";
        std::string target = out;
        if (what == "all") {
            target = (fs::path(out) / export_pass_name(p)).string();
            if (format == "mp4") target += ".mp4";
        }
        ExportOptions eo;
        eo.fps = project.fps;
        eo.project = &project;
        eo.edits = &edits;
        eo.first = a.get_int("first", 0);
        eo.last = a.get_int("last", -1);
        StageProgress bar(std::string("export ") + export_pass_name(p));
        eo.progress = [&](int done, int total) {
            bar.update(total > 0 ? double(done) / total : 0.0,
                       "frame " + std::to_string(done) + "/" + std::to_string(total));
            return true;
        };
        FallbackShare share;
        eo.fallback = &share;
        auto files = export_pass(*engine, p, format, target, eo);
        bar.done(std::to_string(files.size()) + " file(s)");
        std::printf("%s: %zu file(s) in %s\n", export_pass_name(p), files.size(), target.c_str());
        // Never worse than the shot, and say so (docs/method.md, Confidence and fallback).
        if (share.frames > 0) std::printf("  %s\n", share.summary().c_str());
    }
    if (timing_enabled()) std::fprintf(stderr, "%s", timing_table().c_str());
    return 0;
}

}  // namespace refocus
