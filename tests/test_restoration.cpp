// The output rules at the defaults, end to end on a clean and a noisy copy of one synth clip: on
// the clean clip, where the model is right, the plate keeps the fit's gain; with σ 4 noise added
// it is never worse than the shot; the clip's noise is measured on both.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "io/clip.h"
#include "io/image.h"
#include "metrics/metrics.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// σ (levels) as `refocus new` and `info` report it: "noise: sigma 4.10 levels (...)".
double reported_noise(const std::string& output) {
    const auto at = output.find("noise:");
    REQUIRE(at != std::string::npos);
    const auto s = output.find("sigma ", at);
    REQUIRE(s != std::string::npos);
    return std::stod(output.substr(s + 6));
}

// Gaussian noise of `sigma` levels added to every input frame in 8-bit sRGB, rounded and
// clipped as a camera file holds it; the rest of the clip (truth, radius) is linked unchanged.
fs::path noisy_copy(const TinyClip& c, double sigma) {
    const fs::path out = c.dir / "noisy";
    fs::create_directories(out);
    for (const auto& e : fs::directory_iterator(c.clip))
        if (e.path().filename().string().rfind("input_", 0) != 0)
            fs::copy_file(e.path(), out / e.path().filename(),
                          fs::copy_options::overwrite_existing);
    const auto frames = read_all_frames((c.clip / "input_%04d.png").string());
    std::mt19937 rng(11);
    std::normal_distribution<double> n(0.0, sigma);
    std::vector<Image> noisy;
    for (Image f : frames) {
        for (float& v : f.pixels) {
            const double code = std::round(255.0 * linear_to_srgb(v) + n(rng));
            v = srgb8_to_linear_table()[int(std::clamp(code, 0.0, 255.0))];
        }
        noisy.push_back(std::move(f));
    }
    write_png_sequence(out / "png", noisy);
    for (size_t t = 0; t < noisy.size(); ++t) {
        char from[32], to[32];
        std::snprintf(from, sizeof from, "frame_%04zu.png", t);
        std::snprintf(to, sizeof to, "input_%04zu.png", t);
        fs::rename(out / "png" / from, out / to);
    }
    return out;
}

struct Scores {
    double input = 0, plate = 0, model = 0, worst = 1e9;
    double untrusted = 0;  // the plate with fit.explained_rms 0 (the rules of a fit not trusted)
    bool trusted = false;  // export said the fit explains the clip
};

// Fits the project at the defaults for `iters` steps (estimated radius), then scores its plate
// at the default rules and with every output rule off (the model alone, the same checkpoint).
Scores fit_and_score(const TinyClip& c, const fs::path& clip, int iters) {
    RunResult r = cli("fit '" + c.project.string() + "' --iters " + std::to_string(iters));
    INFO(r.output);
    REQUIRE(r.code == 0);
    const auto gt = read_all_frames((clip / "sharp_%04d.png").string());
    const auto input = read_all_frames((clip / "input_%04d.png").string());
    std::string said;
    const auto plate = export_sharp(c, "plate", &said);
    set_project_setting(c.project, "fit.explained_rms", 0.0);
    const auto untrusted = export_sharp(c, "untrusted");
    for (const char* rule :
         {"fit.fallback_k", "fit.trust_seen_px", "fit.sharper_view_px", "fit.keep_focus_px"})
        set_project_setting(c.project, rule, 0.0);
    const auto model = export_sharp(c, "model");
    REQUIRE(plate.size() == gt.size());
    REQUIRE(model.size() == gt.size());
    REQUIRE(untrusted.size() == gt.size());
    Scores s;
    s.trusted = said.find("the fit explains the clip") != std::string::npos;
    const double T = double(gt.size());
    for (size_t t = 0; t < gt.size(); ++t) {
        const double in = psnr(input[t], gt[t]), out = psnr(plate[t], gt[t]);
        s.input += in / T;
        s.plate += out / T;
        s.model += psnr(model[t], gt[t]) / T;
        s.untrusted += psnr(untrusted[t], gt[t]) / T;
        s.worst = std::min(s.worst, out - in);
    }
    return s;
}

}  // namespace

TEST_CASE("the defaults keep a right model's gain on clean footage, and the shot under noise") {
    TinyClip c = make_tiny("restoration_clean", "rack", "160x90");
    RunResult r = cli("info '" + c.project.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const double clean_sigma = reported_noise(r.output);
    const Scores clean = fit_and_score(c, c.clip, 150);
    MESSAGE("clean rack: input " << clean.input << " dB, plate " << clean.plate << " (worst frame "
                                 << clean.worst << "), model alone " << clean.model
                                 << ", rules of a fit not trusted " << clean.untrusted
                                 << "; noise read " << clean_sigma << " levels");

    TinyClip n;
    n.dir = c.dir / "n4";
    n.clip = noisy_copy(c, 4.0);
    n.project = n.dir / "proj";
    r = cli("new '" + (n.clip / "input_%04d.png").string() + "' -o '" + n.project.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const double noisy_sigma = reported_noise(r.output);
    const Scores noisy = fit_and_score(n, n.clip, 150);
    MESSAGE("rack + σ 4: input " << noisy.input << " dB, plate " << noisy.plate << " (worst frame "
                                 << noisy.worst << "), model alone " << noisy.model
                                 << ", rules of a fit not trusted " << noisy.untrusted
                                 << "; noise read " << noisy_sigma << " levels");

    // The noise: σ 4 within 20 %; the clean clip's pixel-scale texture reads under a level.
    CHECK(std::abs(noisy_sigma - 4.0) < 0.8);
    CHECK(clean_sigma < 1.0);
    // Where the model is right (the clip's lens is the model's pillbox), the rules give away no
    // more than 0.5 dB of the model's own gain: the focus moves 0.2 -> 3 px, under
    // fit.focus_moved_px everywhere, and the layer's travel (fit.focus_travel_px) says the small
    // sharper views are real (without it the plate kept 2.2 of the model's 4.5 dB).
    CHECK(clean.plate > clean.input + 3.0);
    CHECK(clean.plate > clean.model - 0.5);
    // The fit explains the clean clip (its reblur residual is near nothing): the lock reads the
    // model's reblur, not its sharp frame, which gains over the rules of a fit not trusted (the
    // input's low band is the sharp frame's only where the blur is far under the lock's 2 px).
    CHECK(clean.trusted);
    CHECK(clean.plate > clean.untrusted + 0.05);  // 25.41 against 24.84 dB measured
    // Under noise the plate is never worse than the shot, in the mean or in any frame.
    CHECK(noisy.plate > noisy.input);
    CHECK(noisy.worst > -0.5);
}
