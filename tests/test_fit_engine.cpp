// The fit end to end on tiny generated clips: it beats its input, resumes after kill -9 to the
// same result, is deterministic per seed, refuses bad inputs with clear messages, and keeps a
// patch no layer explains out of the shared atlas.
#include <nlohmann/json.hpp>
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

#include "io/clip.h"
#include "metrics/metrics.h"
#include "fit/fit_engine.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("fast fit of a tiny clip beats its input and exports every pass") {
    TinyClip c = make_tiny("fit_tiny");
    // The sharper-view rule off: the clip is made with the model's own kernel, where the atlas
    // gains even in a frame that is its own sharpest view (the default keeps the shot there).
    RunResult r =
        cli("fit '" + c.project.string() + "' --iters 150 --set fit.sharper_view_px=0 --coc '" +
            (c.clip / "coc_%04d.exr").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("fit done") != std::string::npos);
    auto gt = read_all_frames((c.clip / "sharp_%04d.png").string());
    auto input = read_all_frames((c.clip / "input_%04d.png").string());
    auto sharp = export_sharp(c, "out_sharp");
    REQUIRE(sharp.size() == 8);
    const double in_psnr = mean_psnr(input, gt), out_psnr = mean_psnr(sharp, gt);
    MESSAGE("tiny tripod clip: input " << in_psnr << " dB, fast fit " << out_psnr << " dB");
    CHECK(out_psnr > in_psnr + 0.5);
    for (const auto& f : sharp) CHECK(count_nonfinite(f) == 0);

    r = cli("export '" + c.project.string() + "' --what all --out '" + (c.dir / "all").string() +
            "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    for (const char* f : {"sharp/sharp_0007.png", "reblur/reblur_0000.png", "atlas/atlas_bg.png",
                          "alpha/alpha_0003.png", "coc/coc_0000.exr", "uv/uv_0005.exr"})
        CHECK_MESSAGE(fs::exists(c.dir / "all" / f), f);
    r = cli("export '" + c.project.string() + "' --what sharp --format mp4 --out '" +
            (c.dir / "sharp.mp4").string() + "'");
    CHECK(r.code == 0);
    CHECK(ClipReader::open((c.dir / "sharp.mp4").string())->info().frames == 8);
    // The project remembers the fit.
    r = cli("info '" + c.project.string() + "'");
    CHECK(r.output.find("holds:    fit") != std::string::npos);
}

TEST_CASE("resume after kill -9 matches an uninterrupted run; same seed, same result") {
    TinyClip c = make_tiny("fit_resume");
    const std::string coc = " --coc '" + (c.clip / "coc_%04d.exr").string() + "'";
    RunResult r = cli("fit '" + c.project.string() + "' --iters 40 --seed 5" + coc);
    REQUIRE(r.code == 0);
    auto uninterrupted = export_sharp(c, "a");
    r = cli("fit '" + c.project.string() + "' --iters 40 --seed 5" + coc);
    REQUIRE(r.code == 0);
    auto again = export_sharp(c, "b");
    double same_seed = 0;
    for (size_t i = 0; i < again.size(); ++i)
        same_seed = std::max(same_seed, max_abs_diff(again[i], uninterrupted[i]));
    CHECK(same_seed == 0.0);

    // Checkpoint every step, kill -9 once a checkpoint past step 15 exists, then resume.
    const fs::path ckpt = c.project / "fit" / "checkpoint.json";
    const std::string script =
        "(" + std::string(REFOCUS_CLI) + " fit '" + c.project.string() +
        "' --iters 40 --seed 5 --checkpoint-seconds 0" + coc +
        " >/dev/null 2>&1 & pid=$!; i=0; "
        "while [ $i -lt 600 ]; do "
        "  s=$(grep -o '\"step\": *[0-9]*' '" +
        ckpt.string() +
        "' 2>/dev/null | grep -o '[0-9]*$'); "
        "  if [ -n \"$s\" ] && [ \"$s\" -ge 15 ]; then kill -9 $pid; echo killed at $s; break; fi; "
        "  sleep 0.05; i=$((i+1)); done; wait $pid; echo rc=$?)";
    fs::remove_all(c.project / "fit");
    r = run(script);
    INFO(r.output);
    REQUIRE(r.output.find("killed at") != std::string::npos);
    REQUIRE(r.output.find("rc=137") != std::string::npos);
    auto j = nlohmann::json::parse(read_text_file(ckpt));
    CHECK(j["step"].get<int>() < 40);
    r = cli("fit '" + c.project.string() + "' --resume");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("resumed at step") != std::string::npos);
    auto resumed = export_sharp(c, "c");
    double diff = 0;
    for (size_t i = 0; i < resumed.size(); ++i)
        diff = std::max(diff, max_abs_diff(resumed[i], uninterrupted[i]));
    MESSAGE("resumed vs uninterrupted: max abs diff " << diff);
    CHECK(diff < 1e-6);
}

TEST_CASE("fit refuses bad inputs with messages naming the problem") {
    TinyClip c = make_tiny("fit_bad");
    // --coc with the wrong count.
    fs::create_directories(c.dir / "few");
    for (int i = 0; i < 3; ++i)
        fs::copy_file(c.clip / ("coc_000" + std::to_string(i) + ".exr"),
                      c.dir / "few" / ("coc_000" + std::to_string(i) + ".exr"));
    RunResult r = cli("fit '" + c.project.string() + "' --iters 2 --coc '" +
                      (c.dir / "few" / "coc_%04d.exr").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("coc_0003.exr") != std::string::npos);
    CHECK(r.output.find("missing") != std::string::npos);
    // --coc with the wrong size.
    RunResult s =
        cli("synth --scene rack -o '" + (c.dir / "big").string() + "' --size 80x40 --frames 8");
    REQUIRE(s.code == 0);
    r = cli("fit '" + c.project.string() + "' --iters 2 --coc '" +
            (c.dir / "big" / "coc_%04d.exr").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("80x40") != std::string::npos);
    // Not a project / nothing fitted yet / resume without checkpoint.
    r = cli("fit '" + (c.dir / "nothing").string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("nothing") != std::string::npos);
    r = cli("export '" + c.project.string() + "' --what sharp --out '" + (c.dir / "x").string() +
            "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("not been fitted") != std::string::npos);
    r = cli("fit '" + c.project.string() + "' --resume --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("nothing to resume") != std::string::npos);
    r = cli("fit '" + c.project.string() + "' --preset magic --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("unknown preset") != std::string::npos);
    r = cli("fit '" + c.project.string() + "' --batch 0 --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("--batch must be at least 1") != std::string::npos);
}

TEST_CASE("robust weights: a patch no layer can explain does not leak into the shared atlas") {
    // A static one-layer clip whose frame 2 carries a bright square (a flash, a passer-by the
    // masks missed): the atlas is shared, so the square can only be explained in frame 2 at the
    // cost of the other frames. With robust weights the square's pixels soon stop pulling.
    const int64_t T = 6, H = 36, W = 48;
    torch::manual_seed(0);
    auto clean = torch::rand({1, 3, H / 4, W / 4});
    clean =
        torch::nn::functional::interpolate(clean, torch::nn::functional::InterpolateFuncOptions()
                                                      .size(std::vector<int64_t>{H, W})
                                                      .mode(torch::kBilinear)
                                                      .align_corners(false));
    auto make = [&] {
        auto d = std::make_shared<FitData>();
        d->frames = T, d->height = H, d->width = W;
        d->input = clean.expand({T, 3, H, W}).clone();
        d->input[2].narrow(1, 10, 14).narrow(2, 16, 14).fill_(1.0);
        d->radius = torch::full({T, H, W}, 0.0);
        d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
        return d;
    };
    auto patch = [](const torch::Tensor& x) { return x.narrow(-2, 10, 14).narrow(-1, 16, 14); };
    double fallback_in = 0, fallback_out = 1;
    auto leak = [&](double c) {
        FitOptions o;
        o.preset = "fast";
        o.iters = 300;
        o.robust_c = c;
        o.fallback_frames = 0;  // frame by frame here (the window has a test of its own)
        o.fallback_change = 0;  // the rank rule, at k 4 and 0.04: frame 0 rightly falls back
        o.fallback_k = 4;       // where the square leaked with robust weights off at lower
        o.fallback_min = 0.04;  // thresholds, and under the evidence rule
        o.keep_focus_px = 0;    // the clip has no blur: with it on, every frame is the shot
        FitEngine e(make(), o);
        while (!e.done()) e.step();
        auto s = e.render_frame(0).sharp;  // a frame without the square
        auto diff = patch(s[0] - clean[0]).abs().mean().item<double>();
        REQUIRE(std::isfinite(diff));
        // The sharp plate of frame 2 falls back to the shot at the patch only; frame 0 keeps
        // the fit everywhere.
        auto f = e.fallback_weight(2);
        REQUIRE(f.defined());
        fallback_in = patch(f).mean().item<double>();
        fallback_out = f[0][0].narrow(1, 0, 6).max().item<double>();
        auto f0 = e.fallback_weight(0);
        CHECK((!f0.defined() || f0.max().item<double>() < 0.05));
        Layers L2 = e.render_frame(2);
        const torch::Tensor model_sharp = L2.sharp;
        e.apply_fallback(L2, 2);
        CHECK(patch(L2.sharp[0]).mean().item<double>() > 0.9);
        // Paint drawn into the frame (an atlas edit) stays on top of the fallback, also where
        // the frame falls back to the shot.
        Layers L3 = e.render_frame(2);
        auto paint = torch::zeros_like(L3.sharp);
        paint.narrow(-2, 12, 4).narrow(-1, 18, 4).fill_(-0.5);  // inside the patch
        L3.sharp = L3.sharp + paint;
        Layers model;
        model.sharp = model_sharp;
        e.apply_fallback(L3, 2, &model);
        CHECK((L3.sharp - L2.sharp - paint).abs().max().item<double>() < 1e-5);
        return diff;
    };
    const double off = leak(0.0), on = leak(1.5);
    MESSAGE("fallback weight of frame 2: patch " << fallback_in << ", left 6 columns at most "
                                                 << fallback_out);
    CHECK(fallback_in > 0.9);
    CHECK(fallback_out < 0.05);
    MESSAGE("square leaking into frame 0: robust off " << off << ", on " << on);
    CHECK(on < 0.6 * off);
}
