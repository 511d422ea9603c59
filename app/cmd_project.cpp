// refocus new / refocus info
#include <unistd.h>

#include <csignal>
#include <cstdio>

#include "args.h"
#include "commands.h"
#include "progress.h"
#include "fit/fit_engine.h"
#include "io/clip.h"
#include "prepare/noise.h"
#include "project/project.h"
#include "util/error.h"
#include "util/validate.h"

namespace refocus {

namespace {

volatile std::sig_atomic_t g_interrupted = 0;

void print_progress(StageProgress& p, int i, int n) {
    // Thrown from here, the ingest removes its temporary folder: no partial project.
    if (g_interrupted) throw Error("interrupted: no project was created");
    const std::string frames = "frame " + std::to_string(i) + "/" + std::to_string(n);
    if (i == n)
        p.done(frames);
    else
        p.update(n > 0 ? double(i) / n : 0.0, frames);
}

ClipReadOptions read_options(const Args& a) {
    ClipReadOptions o;
    o.default_fps = checked_range("--fps", a.get_double("fps", 24.0), 0.0, 1000.0, true);
    o.fps_override = a.has("fps");  // a video's own rate too: a user who says --fps means it
    std::string nf = a.get("nonfinite", "reject");
    if (nf == "reject")
        o.nonfinite = NonFinitePolicy::Reject;
    else if (nf == "clean")
        o.nonfinite = NonFinitePolicy::Clean;
    else
        throw Error("--nonfinite must be 'reject' or 'clean' (got '" + nf + "')");
    return o;
}

}  // namespace

int cmd_new(int argc, char** argv) {
    Args a(argc, argv, 2);
    a.check_known({"out", "fps", "nonfinite", "first", "last"});
    if (a.positional().size() != 1 || !a.has("out"))
        throw Error("usage: refocus new <clip> -o <project-dir> [--first N] [--last N]");
    const std::string clip = a.positional()[0];
    ClipReadOptions opts = read_options(a);
    opts.first = a.get_int("first", 0);
    opts.last = a.get_int("last", -1);
    if (opts.first < 0 || (a.has("last") && opts.last < opts.first))
        throw Error("--first and --last name frames from 0, first <= last (got " +
                    a.get("first", "0") + ".." + a.get("last", "end") + ")");
    std::signal(SIGINT, [](int) { g_interrupted = 1; });
    std::signal(SIGTERM, [](int) { g_interrupted = 1; });
    StageProgress progress("ingest");
    Project p = create_project(clip, a.get("out"), opts,
                               [&](int i, int n) { print_progress(progress, i, n); });
    if (a.has("fps") && !is_project_path(clip) && is_video_path(clip))
        std::fprintf(stderr, "note: --fps %g replaces the video's own frame rate\n", p.fps);
    std::printf("created project %s: %dx%d, %d frames at %.3f fps from %s%s\n",
                p.project_file().string().c_str(), p.width, p.height, p.frames, p.fps, clip.c_str(),
                p.sections.contains("source_range")
                    ? (" (frames " + std::to_string(opts.first) + ".." +
                       std::to_string(opts.first + p.frames - 1) + ")")
                          .c_str()
                    : "");
    std::printf("noise: %s\n", project_noise(p).describe().c_str());
    return 0;
}

int cmd_info(int argc, char** argv) {
    Args a(argc, argv, 2);
    a.check_known({"fps", "nonfinite"});
    if (a.positional().size() != 1) throw Error("usage: refocus info <clip-or-project>");
    const std::string path = a.positional()[0];
    if (is_project_path(path)) {
        Project p = Project::load(path);
        std::printf("project:  %s\n", p.project_file().string().c_str());
        std::printf("name:     %s\n", p.name.c_str());
        std::printf("version:  %d\n", p.version);
        std::printf("source:   %s (%s, %s)\n", p.source.c_str(), p.source_kind.c_str(),
                    p.source_format.c_str());
        std::printf("size:     %dx%d\n", p.width, p.height);
        std::printf("frames:   %d\n", p.frames);
        std::printf("fps:      %.3f\n", p.fps);
        std::printf("cache:    %s\n", (p.dir / p.frame_pattern).string().c_str());
        const bool stored = p.sections.contains("noise");
        std::printf("noise:    %s%s\n", project_noise(p).describe().c_str(),
                    stored ? "" : ", measured now (the project predates the stored estimate)");
        if (p.sections.empty() || (stored && p.sections.size() == 1)) {
            std::printf("holds:    frames only (not fitted yet)\n");
        } else {
            for (auto it = p.sections.begin(); it != p.sections.end(); ++it) {
                if (it.key() == "noise") continue;
                if (it.key() != "fit") {
                    std::printf("holds:    %s\n", it.key().c_str());
                    continue;
                }
                // A fit is what fit --resume, export and the studio can load: say so only then.
                const fs::path dir = p.dir / "fit";
                if (!FitEngine::has_checkpoint(dir)) {
                    std::printf("holds:    fit settings (no checkpoint yet)\n");
                    continue;
                }
                const std::string why = FitEngine::checkpoint_problem(dir, p.frames);
                if (why.empty())
                    std::printf("holds:    fit\n");
                else
                    std::printf(
                        "holds:    fit settings; the checkpoint cannot be used (%s): run "
                        "refocus fit %s to fit again\n",
                        why.c_str(), p.dir.string().c_str());
            }
        }
        return 0;
    }
    auto reader = ClipReader::open(path, read_options(a));
    const ClipInfo& i = reader->info();
    std::printf("clip:     %s\n", i.path.c_str());
    std::printf("kind:     %s\n", i.kind.c_str());
    std::printf("size:     %dx%d\n", i.width, i.height);
    std::printf("frames:   %d\n", i.frames);
    std::printf("fps:      %.3f%s\n", i.fps,
                i.kind == "sequence" ? " (sequence: --fps sets it)" : "");
    std::printf("source:   %d channel(s), %s, %s\n", i.source_channels, i.source_format.c_str(),
                i.source_linear ? "linear" : "sRGB-encoded");
    if (!i.note.empty()) std::printf("note:     %s\n", i.note.c_str());
    return 0;
}

}  // namespace refocus
