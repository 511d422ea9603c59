// refocus synth: procedural misfocused clips with exact ground truth (engine/synth/synth.h).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>

#include "args.h"
#include "commands.h"
#include "io/image_file.h"
#include "synth/synth.h"
#include "util/error.h"

namespace refocus {

namespace {

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
    opts.fps = args.get_double("fps", opts.fps);
    if (args.has("blades")) {
        opts.shape = ApertureShape::Blades;
        opts.blades = args.get_int("blades", 6);
        opts.rotation_deg = args.get_double("rotation", 0.0);
    }
    const std::string out = args.get("out");
    if (out.empty()) throw Error("synth needs an output folder: -o DIR");
    const bool quiet = args.has("quiet");

    const auto t0 = std::chrono::steady_clock::now();
    SynthClip probe(opts);  // validates the options before any file is written
    auto files = write_synth_clip(opts, out, [&](int t) {
        if (!quiet)
            std::fprintf(stderr, "\rsynth %s: frame %d/%d", scene.c_str(), t + 1, opts.frames);
    });
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
