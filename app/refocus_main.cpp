// refocus: the command-line front end. Thin: parse arguments, call the engine.
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>

#include "commands.h"
#include "fit/presets.h"
#include "util/debug.h"
#include "util/json_file.h"
#include "util/allocator.h"
#include "util/threads.h"

namespace {

struct Command {
    const char* name;
    int (*run)(int, char**);
    const char* usage;
    const char* help;
};

const Command kCommands[] = {
    {"new", refocus::cmd_new,
     "new <clip> -o <project-dir> [--fps F] [--nonfinite reject|clean] [--first N] [--last N]",
     "ingest a video or image sequence into a new project"},
    {"info", refocus::cmd_info, "info <clip-or-project>",
     "print size, frames, fps and what a project holds"},
    {"bench", refocus::cmd_bench, "bench blur|fit|corpus|motion|kernel|bound [options]",
     "print benchmark figures (bench with no name lists them with their options)"},
    {"fit", refocus::cmd_fit,
     "fit <project> [--preset P] [--minutes M | --iters N] [--coc <pattern>]\n"
     "           [--mask <pattern>] [--seed S] [--batch N] [--set name=value]... [--resume]\n"
     "           [--reprepare] [--checkpoint-seconds S]\n"
     "       fit --list-settings",
     "fit sharp layered atlases to the project's clip (checkpoints; --resume continues);\n"
     "           --coc: per-frame EXR circle-of-confusion radii in px, instead of the estimate;\n"
     "           --batch: frames per step (left out: 4 where a layer has the deblurring path, else "
     "2);\n"
     "           --set: a tuning setting (kept in project.json; --list-settings lists them)"},
    {"export", refocus::cmd_export,
     "export <project> --what "
     "sharp|reblur|atlas|alpha|coc|uv|refocus|depth|confidence|flow|parallax|all\n"
     "           [--format png|exr|tiff|mp4] [--first N] [--last N] --out <dir-or-file>",
     "write the fit's results: sequences <what>_%04d.<ext> from 0, or an mp4"},
    {"atlas", refocus::cmd_atlas,
     "atlas <project> --import <file> --layer bg|fg | --clear [--layer bg|fg]",
     "bring back a repainted atlas (PNG/TIFF/EXR): the edit follows every frame"},
    {"batch", refocus::cmd_batch,
     "batch plan|run|status|submit <shots.json|.csv> [--jobs N]\n"
     "           submit: [--partition P] [--account A] [--cpus N] [--time MIN] [--mem MB]\n"
     "           [--max-running K] [--dry-run]",
     "many shots from a shot list: ingest, fit and export each, N at once here or as a Slurm\n"
     "           job array; what is done is skipped, an unfinished fit resumes (docs/method.md)"},
    {"synth", refocus::cmd_synth,
     "synth --scene rack|walkout|pan|hunt|tripod|pillar|list -o <dir> [--size WxH] [--frames N] "
     "[--seed S]",
     "render a misfocused test clip with exact ground truth (sharp, COC, alpha, flow)"},
};

void print_help() {
    std::printf(
        "refocus - fix misfocused video: fit sharp layered atlases, refocus, export\n\n"
        "usage: refocus <command> [options]\n\ncommands:\n");
    for (const auto& c : kCommands)
        std::printf("  %-8s %s\n           %s\n", c.name, c.help, c.usage);
    std::printf("\npresets (fit --preset):\n");
    for (const auto& p : refocus::fit_presets())
        std::printf("  %-8s %s\n", p.name.c_str(), p.description.c_str());
    std::printf(
        "\nClips are video files (mp4, mov, mkv, avi) or image sequences: a folder, or a\n"
        "frame pattern with one %%d or %%0Nd, such as shot/frame_%%04d.exr (PNG, JPEG, TIFF,\n"
        "OpenEXR).\n"
        "Any command takes --debug <what>[,<what>...] for diagnostics:");
    for (const auto& [name, help] : refocus::debug_names()) std::printf(" %s", name.c_str());
    std::printf("\n");
}

}  // namespace

int main(int argc, char** argv) {
    // OpenMP threads spin-wait by default; with any other process on the cores (a second fit,
    // the studio, a test running beside) that wastes most of the CPU (measured: 17x slower
    // pre-training). libgomp reads the policy when it loads, so set it and start again.
    if (!std::getenv("OMP_WAIT_POLICY")) {
        setenv("OMP_WAIT_POLICY", "PASSIVE", 1);
        execv("/proc/self/exe", argv);  // on failure, carry on as we are
    }
    // Lines reach a log file as they are written, not when the command exits.
    std::setvbuf(stdout, nullptr, _IOLBF, 0);
    if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h") ||
        !std::strcmp(argv[1], "help")) {
        print_help();
        return argc < 2 ? 2 : 0;
    }
    if (!std::strcmp(argv[1], "--version")) {
        std::printf("refocus 0.1.0\n");
        return 0;
    }
    // --debug is every command's: taken out here, so that commands see only their own options.
    std::string debug;
    for (int i = 2; i < argc; ++i) {
        std::string a = argv[i];
        if (a == "--debug" && i + 1 < argc) {
            debug += (debug.empty() ? "" : ",") + std::string(argv[i + 1]);
            for (int k = i; k + 2 <= argc; ++k) argv[k] = argv[k + 2];
            argc -= 2;
            --i;
        } else if (a.rfind("--debug=", 0) == 0) {
            debug += (debug.empty() ? "" : ",") + a.substr(8);
            for (int k = i; k + 1 <= argc; ++k) argv[k] = argv[k + 1];
            argc -= 1;
            --i;
        }
    }
    for (const auto& c : kCommands) {
        if (std::strcmp(argv[1], c.name) != 0) continue;
        // Every command answers --help (a value of an option never is "--help").
        for (int i = 2; i < argc; ++i)
            if (!std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h")) {
                std::printf("usage: refocus %s\n\n  %s\n", c.usage, c.help);
                return 0;
            }
        try {
            if (!debug.empty()) refocus::set_debug(debug);
            refocus::tune_allocator();
            refocus::init_threads();
            return c.run(argc, argv);
        } catch (const std::exception& e) {
            // One line: library errors (LibTorch's c10::Error) append a stack trace after it.
            std::string what = e.what();
            what = what.substr(0, what.find('\n'));
            if (what.rfind("[json.exception.", 0) == 0)
                what = "malformed JSON: " + refocus::json_error_text(e);
            if (what.empty()) what = "unexpected failure";
            std::fprintf(stderr, "refocus %s: error: %s\n", c.name, what.c_str());
            return 1;
        }
    }
    std::fprintf(stderr, "refocus: unknown command '%s' (see refocus --help)\n", argv[1]);
    return 2;
}
