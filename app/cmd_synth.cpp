// refocus synth: procedural misfocused clips with exact ground truth (engine/synth/synth.h).
#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <string>

#include "args.h"
#include "commands.h"
#include "progress.h"
#include "io/image_file.h"
#include "synth/synth.h"
#include "util/error.h"
#include "util/fs.h"
#include "util/validate.h"

namespace refocus {

namespace {

volatile std::sig_atomic_t g_interrupted = 0;

void parse_size(const std::string& s, int& w, int& h) {
    const auto x = s.find('x');
    try {
        size_t a = 0, b = 0;
        if (x == std::string::npos) throw std::invalid_argument("");
        w = std::stoi(s.substr(0, x), &a);
        h = std::stoi(s.substr(x + 1), &b);
        if (a != x || b != s.size() - x - 1) throw std::invalid_argument("");
    } catch (const std::exception&) {
        throw Error("option --size needs WIDTHxHEIGHT, e.g. 320x180 (got '" + s + "')");
    }
}

}  // namespace

int cmd_synth(int argc, char** argv) {
    Args args(argc, argv, 2, {"quiet"});
    args.check_known({"scene", "out", "size", "frames", "seed", "fps", "blades", "rotation",
                      "triplet", "triplet-frame", "quiet"});
    const std::string scene = args.get("scene");
    if (scene.empty() || scene == "list") {
        if (scene.empty())
            std::printf(
                "usage: refocus synth --scene NAME -o DIR [--size WxH] [--frames N] "
                "[--seed S]\n\nscenes:\n");
        for (const auto& s : synth_scenes())
            std::printf("  %-8s %s\n", s.name.c_str(), s.description.c_str());
        return scene.empty() ? 2 : 0;
    }
    SynthOptions opts;
    opts.scene = scene;
    if (args.has("size")) parse_size(args.get("size"), opts.width, opts.height);
    opts.frames = args.get_int("frames", opts.frames);
    const int seed = args.get_int("seed", 1);
    if (seed < 0) throw Error("option --seed needs an integer >= 0");
    opts.seed = static_cast<uint32_t>(seed);
    opts.fps = checked_range("--fps", args.get_double("fps", opts.fps), 0.0, 1000.0, true);
    if (args.has("blades")) {
        opts.shape = ApertureShape::Blades;
        opts.blades = args.get_int("blades", 6);
        opts.rotation_deg = args.get_double("rotation", 0.0);
    }
    const std::string out = args.get("out");
    if (out.empty()) throw Error("synth needs an output folder: -o DIR");
    const bool quiet = args.has("quiet");
    std::signal(SIGINT, [](int) { g_interrupted = 1; });
    std::signal(SIGTERM, [](int) { g_interrupted = 1; });

    const auto t0 = std::chrono::steady_clock::now();
    SynthClip probe(opts);  // validates the options before any file is written
    // Rendered into a temporary folder and moved into place complete: a failed or interrupted
    // run leaves the output folder as it was.
    if (fs::exists(out) && !fs::is_directory(out))
        throw Error(file_error(out, "exists and is not a folder"));
    const fs::path tmp = make_temp_dir_beside(fs::absolute(out).lexically_normal());
    std::vector<std::string> files;
    StageProgress progress("synth " + scene);
    try {
        files = write_synth_clip(opts, tmp.string(), [&](int t) {
            if (g_interrupted) throw Error("interrupted: " + out + " was left as it was");
            if (quiet) return;
            const std::string f =
                "frame " + std::to_string(t + 1) + "/" + std::to_string(opts.frames);
            if (t + 1 == opts.frames)
                progress.done(f);
            else
                progress.update(double(t + 1) / opts.frames, f);
        });
        publish_dir(tmp, out, {"clip.json"});
    } catch (const Error& e) {
        std::error_code ec;
        fs::remove_all(tmp, ec);
        // Name the files the user asked for, not the temporary ones.
        std::string m = e.what();
        for (size_t at; (at = m.find(tmp.string())) != std::string::npos;)
            m.replace(at, tmp.string().size(), out);
        throw Error(m);
    }
    const double secs =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!quiet) std::fprintf(stderr, "\n");
    std::printf("synth %s: %dx%d, %d frames, seed %u -> %s (%zu files, %.1f s)\n", scene.c_str(),
                opts.width, opts.height, opts.frames, opts.seed, out.c_str(), files.size(), secs);

    if (args.has("triplet")) {
        // input | sharp | COC heat map of one frame, for the README.
        const int t = args.get_int("triplet-frame", opts.frames / 2);
        if (t < 0 || t >= opts.frames)
            throw Error("--triplet-frame must be in [0, " + std::to_string(opts.frames) + ")");
        double rmax = 0;
        const SynthFrame f = probe.render(t);
        for (int k = 0; k < opts.frames; ++k)
            for (double d :
                 {probe.state(k).fg_invdepth, probe.bg_invdepth_top(), probe.bg_invdepth_bottom()})
                rmax = std::max(rmax, probe.lens(k).radius(d));
        write_image_file(args.get("triplet"), synth_triplet(f, rmax), PixelFormat::Png8);
        std::printf("triplet of frame %d -> %s (COC heat map 0..%.1f px)\n", t,
                    args.get("triplet").c_str(), rmax);
    }
    return 0;
}

}  // namespace refocus
