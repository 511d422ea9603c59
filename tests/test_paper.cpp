// The `paper` preset (MLP mappings + deep-image-prior atlases, paper eq. 1) end to end on a
// tiny rack clip: no NaN, sharp frames exported, the reblur PSNR improves, and a checkpoint
// round trip restores identical renders.
#include <doctest/doctest.h>

#include <cstdlib>
#include <regex>

#include "fit/fit_engine.h"
#include "io/clip.h"
#include "metrics/metrics.h"
#include "test_util.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// Reblur PSNR of the first and the last progress line ("reblur_psnr=...").
std::pair<double, double> first_last_psnr(const std::string& out) {
    std::regex re("reblur_psnr=([0-9.]+)");
    std::vector<double> v;
    for (auto it = std::sregex_iterator(out.begin(), out.end(), re); it != std::sregex_iterator(); ++it)
        v.push_back(std::stod((*it)[1]));
    if (v.empty()) return {0, 0};
    return {v.front(), v.back()};
}

}  // namespace

TEST_CASE("paper preset fits a tiny clip, exports, and resumes from a checkpoint exactly") {
    const fs::path dir = scratch_dir("paper_tiny");
    RunResult r = cli("synth --scene rack -o '" + (dir / "clip").string() + "' --size 64x36 --frames 8 --seed 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const fs::path proj = dir / "proj";
    r = cli("new '" + (dir / "clip" / "input_%04d.png").string() + "' -o '" + proj.string() + "'");
    REQUIRE(r.code == 0);
    const std::string coc = " --coc '" + (dir / "clip" / "coc_%04d.exr").string() + "'";
    r = cli("fit '" + proj.string() + "' --preset paper --iters 60" + coc);
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("fit done") != std::string::npos);
    auto [first, last] = first_last_psnr(r.output);
    MESSAGE("paper preset, tiny rack clip: reblur PSNR " << first << " -> " << last << " dB");
    CHECK(last > first);

    r = cli("export '" + proj.string() + "' --what sharp --format exr32 --out '" + (dir / "sharp").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    auto sharp = read_all_frames((dir / "sharp" / "sharp_%04d.exr").string());
    REQUIRE(sharp.size() == 8);
    for (const auto& f : sharp) CHECK(count_nonfinite(f) == 0);

    // Checkpoint round trip in process: a fresh engine (same seed) loading the checkpoint
    // renders exactly what the saved one does.
    auto data = std::make_shared<FitData>();
    data->frames = 4, data->height = 24, data->width = 40;
    torch::manual_seed(7);
    data->input = torch::rand({4, 3, 24, 40});
    data->radius = torch::full({4, 24, 40}, 1.0f);
    data->to_ref = torch::eye(3, torch::kFloat64).expand({4, 3, 3}).clone();
    data->mask = torch::zeros({4, 1, 24, 40});
    data->mask.narrow(2, 8, 8).narrow(3, 12, 10).fill_(1.0f);
    data->has_subject = true;
    data->flow_fwd = torch::zeros({3, 2, 24, 40});
    data->flow_valid = torch::ones({3, 1, 24, 40});
    FitOptions o;
    o.preset = "paper";
    o.iters = 6;
    o.seed = 11;
    FitEngine a(data, o);
    for (int i = 0; i < 3; ++i) a.step();
    const fs::path ck = dir / "ckpt";
    a.save_checkpoint(ck);
    FitEngine b(data, o);
    b.load_checkpoint(ck);
    auto la = a.render_frame(2), lb = b.render_frame(2);
    CHECK(torch::equal(la.sharp, lb.sharp));
    CHECK(torch::equal(la.alpha, lb.alpha));
    CHECK(torch::equal(a.model().atlas_fg(), b.model().atlas_fg()));
    // Both continue identically.
    a.step(), b.step();
    CHECK(torch::equal(a.render_frame(1).sharp, b.render_frame(1).sharp));
    CHECK_THROWS_WITH_AS(b.model().set_atlas_bg(a.model().atlas_bg()),
                         doctest::Contains("use the fast preset"), Error);
}
