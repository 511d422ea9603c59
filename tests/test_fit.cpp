// The fit end to end on tiny generated clips: it beats its input, resumes after kill -9 to the
// same result, is deterministic per seed, and refuses bad inputs with clear messages.
#include <nlohmann/json.hpp>
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <sstream>

#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "model/atlas_geometry.h"
#include "fit/fast_model.h"
#include "fit/fit_engine.h"
#include "session/fit_session.h"
#include "fit/fit_setup.h"
#include "fit/losses.h"
#include "radius/stack_coc.h"
#include "project/project.h"
#include "test_util.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// A tiny rack-focus clip with ground truth, and a project made from its input frames.
struct TinyClip {
    fs::path dir, clip, project;
};

TinyClip make_tiny(const std::string& name, const std::string& scene = "tripod",
                   const std::string& size = "64x36") {
    TinyClip c;
    c.dir = scratch_dir(name);
    c.clip = c.dir / "clip";
    RunResult r = cli("synth --scene " + scene + " -o '" + c.clip.string() +
                      "' --size " + size + " --frames 8 --seed 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    c.project = c.dir / "proj";
    r = cli("new '" + (c.clip / "input_%04d.png").string() + "' -o '" + c.project.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    return c;
}

std::vector<Image> export_sharp(const TinyClip& c, const std::string& sub) {
    fs::path out = c.dir / sub;
    RunResult r = cli("export '" + c.project.string() + "' --what sharp --format exr32 --out '" +
                      out.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    return read_all_frames((out / "sharp_%04d.exr").string());
}

}  // namespace

TEST_CASE("fast fit of a tiny clip beats its input and exports every pass") {
    TinyClip c = make_tiny("fit_tiny");
    RunResult r = cli("fit '" + c.project.string() + "' --iters 150 --coc '" +
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

    r = cli("export '" + c.project.string() + "' --what all --out '" + (c.dir / "all").string() + "'");
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

TEST_CASE("fast model renders a margin past the frame edge; the reblur crops it back; checkpoints keep the figures") {
    // Near an edge the lens gathered light from outside the frame: the atlas reaches past it by
    // the widest blur support, and training blurs the padded render (FitModel::render_padded).
    const int64_t T = 3, H = 24, W = 32;
    torch::manual_seed(0);
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->input = torch::rand({T, 3, H, W});
    d->radius = torch::full({T, H, W}, 2.0);
    d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    FitOptions o;
    o.preset = "fast";
    o.iters = 1;
    FitEngine e(d, o);
    const int64_t P = e.model().max_pad();
    REQUIRE(P >= 3);  // support of a 2 px disk plus its soft edge
    Layers a = e.model().render({0, 2}), b = e.model().render_padded({0, 2}, P);
    REQUIRE(b.sharp.size(2) == H + 2 * P);
    REQUIRE(b.sharp.size(3) == W + 2 * P);
    CHECK(torch::allclose(b.sharp.narrow(2, P, H).narrow(3, P, W), a.sharp, 1e-5, 1e-5));
    // The margin starts as the frame's edge carried outward.
    CHECK((b.sharp.select(3, 0) - b.sharp.select(3, P)).abs().max().item<double>() < 1e-4);
    CHECK((b.sharp.select(2, H + 2 * P - 1) - b.sharp.select(2, P + H - 1)).abs().max().item<double>() < 1e-4);
    auto rb = e.reblur(b, {0, 2}), rb0 = e.reblur(a, {0, 2});
    REQUIRE(rb.sizes() == rb0.sizes());
    // Two supports from the edges the two agree; at the edge they differ.
    auto inner = [&](const torch::Tensor& x) {
        return x.narrow(2, 2 * P, H - 4 * P).narrow(3, 2 * P, W - 4 * P);
    };
    CHECK(torch::allclose(inner(rb), inner(rb0), 1e-4, 1e-4));
    CHECK(!torch::allclose(rb.select(3, 0), rb0.select(3, 0), 1e-3, 1e-3));
    CHECK(torch::isfinite(rb).all().item<bool>());
    CHECK_THROWS_WITH_AS(e.model().render_padded({0}, P + 1), doctest::Contains("padding"), Error);
    e.step();
    CHECK(e.snapshot().step == 1);

    // A checkpoint keeps the last step's figures: a reopened project shows them, not zeros.
    const fs::path ck = scratch_dir("fit_checkpoint_figures");
    e.save_checkpoint(ck);
    FitEngine e2(d, o);
    e2.load_checkpoint(ck);
    CHECK(e2.snapshot().step == 1);
    CHECK(e2.snapshot().loss == doctest::Approx(e.snapshot().loss));
    CHECK(e2.snapshot().loss > 0);
    CHECK(e2.snapshot().reblur_psnr == doctest::Approx(e.snapshot().reblur_psnr));
    CHECK(e2.snapshot().terms.count("l1") == 1);
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
    for (size_t i = 0; i < again.size(); ++i) same_seed = std::max(same_seed, max_abs_diff(again[i], uninterrupted[i]));
    CHECK(same_seed == 0.0);

    // Checkpoint every step, kill -9 once a checkpoint past step 15 exists, then resume.
    const fs::path ckpt = c.project / "fit" / "checkpoint.json";
    const std::string script =
        "(" + std::string(REFOCUS_CLI) + " fit '" + c.project.string() +
        "' --iters 40 --seed 5 --checkpoint-seconds 0" + coc +
        " >/dev/null 2>&1 & pid=$!; i=0; "
        "while [ $i -lt 600 ]; do "
        "  s=$(grep -o '\"step\": *[0-9]*' '" + ckpt.string() + "' 2>/dev/null | grep -o '[0-9]*$'); "
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
    for (size_t i = 0; i < resumed.size(); ++i) diff = std::max(diff, max_abs_diff(resumed[i], uninterrupted[i]));
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
    RunResult s = cli("synth --scene rack -o '" + (c.dir / "big").string() + "' --size 80x40 --frames 8");
    REQUIRE(s.code == 0);
    r = cli("fit '" + c.project.string() + "' --iters 2 --coc '" + (c.dir / "big" / "coc_%04d.exr").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("80x40") != std::string::npos);
    // Not a project / nothing fitted yet / resume without checkpoint.
    r = cli("fit '" + (c.dir / "nothing").string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("nothing") != std::string::npos);
    r = cli("export '" + c.project.string() + "' --what sharp --out '" + (c.dir / "x").string() + "'");
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

TEST_CASE("bench fit prints run time against error and writes the CSV; --batch reaches the engine") {
    TinyClip c = make_tiny("fit_bench");
    const fs::path csv = c.dir / "bench.csv", work = c.dir / "bench_work";
    RunResult r = cli("bench fit --clip '" + c.clip.string() + "' --preset fast --iters 12 --at 0,0.0001 --batch 3 "
                      "--oracle-coc --csv '" + csv.string() + "' --work '" + work.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("radius ground truth") != std::string::npos);
    CHECK(r.output.find("(end)") != std::string::npos);
    CHECK(r.output.find("gain over input") != std::string::npos);
    // The end's error by spatial frequency: every band from 0 to 0.71 cycles/px, the input's beside.
    CHECK(r.output.find("error by spatial frequency") != std::string::npos);
    CHECK(r.output.find("  0.00-0.02 ") != std::string::npos);
    CHECK(r.output.find("  0.50-0.71 ") != std::string::npos);
    std::ifstream in(csv);
    REQUIRE(in.good());
    std::string header, line;
    std::getline(in, header);
    CHECK(header.rfind("clip,preset,radius,minutes,step,psnr,ssim,tpsnr,reblur_psnr", 0) == 0);
    std::vector<std::string> rows;
    while (std::getline(in, line))
        if (!line.empty()) rows.push_back(line);
    REQUIRE(rows.size() >= 2);  // the first step (--at 0) and the end
    // The last row: the end, step 12, finite figures above 0 dB.
    std::vector<std::string> f;
    std::stringstream ss(rows.back());
    for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
    REQUIRE(f.size() == 13);
    CHECK(f[0] == "clip");
    CHECK(f[1] == "fast");
    CHECK(f[2] == "oracle");
    CHECK(std::stoi(f[4]) == 12);
    for (int i : {5, 7, 8, 9}) {
        CHECK(std::isfinite(std::stod(f[i])));
        CHECK(std::stod(f[i]) > 5.0);
    }
    // The fitted project is kept for export; its settings hold the batch the bench was given.
    CHECK(fs::exists(work / "project.json"));
    CHECK(read_fit_settings(Project::load(work)).fit.batch == 3);
    r = cli("bench fit --clip '" + c.dir.string() + "' --preset fast --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find("no clip.json") != std::string::npos);
}

TEST_CASE("a subject seen smaller than in its atlas: the atlas is prefiltered for the footprint") {
    // A point spreads to the footprint's box variance less the texel's own: (s² − 1)/12 a side.
    auto impulse = torch::zeros({1, 3, 21, 21});
    impulse.index_put_({0, torch::indexing::Slice(), 10, 10}, 1.0f);
    for (double s : {1.5, 2.5, 4.0}) {
        auto f = prefilter_for_footprint(impulse, s);
        REQUIRE(f.sizes() == impulse.sizes());
        auto x = torch::arange(-10, 11, torch::kFloat32);
        const double sum = f[0][1].sum().item<double>();
        const double var_x = (f[0][1] * (x * x).view({1, 21})).sum().item<double>() / sum;
        const double var_y = (f[0][1] * (x * x).view({21, 1})).sum().item<double>() / sum;
        INFO("s " << s << ": variance " << var_x << " x " << var_y);
        CHECK(sum == doctest::Approx(1.0).epsilon(1e-5));  // light is kept
        CHECK(var_x == doctest::Approx((s * s - 1) / 12).epsilon(0.03));
        CHECK(var_y == doctest::Approx(var_x).epsilon(1e-5));
    }
    // No minification (or a magnification): the atlas as it is; a flat atlas stays flat.
    CHECK(prefilter_for_footprint(impulse, 1.0).is_same(impulse));
    CHECK(prefilter_for_footprint(impulse, 0.5).is_same(impulse));
    auto flat = torch::full({1, 3, 9, 12}, 0.4f);
    CHECK((prefilter_for_footprint(flat, 3.0) - 0.4f).abs().max().item<float>() < 1e-6f);

    // A subject walking away (masks given: 8 frames of a tiny clip are too few for automatic
    // ones): the fit says that it prefilters, and its sharp frames stay finite.
    TinyClip c = make_tiny("fit_walkaway", "walkout", "160x90");
    RunResult r = cli("fit '" + c.project.string() + "' --preset fast --iters 3 --coc '" +
                      (c.clip / "coc_%04d.exr").string() + "' --mask '" + (c.clip / "alpha_%04d.png").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("the subject's size changes along the clip") != std::string::npos);
    CHECK(r.output.find("prefiltered for each frame where the subject is smaller") != std::string::npos);
    for (const auto& img : export_sharp(c, "sharp"))
        for (float v : img.pixels) REQUIRE(std::isfinite(v));
}

TEST_CASE("bench bound: the wall's ceiling and Wiener bound against the truth; bad clips refused") {
    TinyClip c = make_tiny("fit_bound", "walkout", "160x90");
    // A fit's sharp frames are scored on the same pixels: the truth itself scores far above all.
    RunResult r = cli("bench bound --clip '" + c.clip.string() + "' --lambdas 1e-6,1e-5 --iters 60 --sharp '" +
                      c.clip.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    auto figure = [&](const std::string& label) {
        const auto at = r.output.find(label);
        REQUIRE(at != std::string::npos);
        const auto eol = r.output.find('\n', at);
        const auto last = r.output.rfind(' ', eol);  // the figure ends the line
        return std::stod(r.output.substr(last + 1, eol - last - 1));
    };
    const double input = figure("input"), ceiling = figure("ceiling: the truth on one phase");
    const double b6 = figure("bound: Wiener at lambda 1e-06");
    const double b5 = figure("bound: Wiener at lambda 1e-05");
    const double truth = figure("fit (--sharp)");
    // The deconvolution restores what the blur took (walkout's wall: 2.5-4.7 px here), and
    // stays under the best a 1x atlas holds, which stays under the truth itself.
    CHECK(b5 > input + 2.0);
    CHECK(b6 > input + 1.0);
    CHECK(ceiling > std::max(b5, b6) + 2.0);
    CHECK(truth > ceiling + 20.0);
    CHECK(r.output.find("best bound") != std::string::npos);

    // A focus that moves gives each frame its own blur per wall point: refused, naming the file.
    const std::string coc3 = (c.clip / "coc_0003.exr").string();
    Image coc = read_image_file(coc3, false).image;
    for (auto& v : coc.pixels) v *= 1.5f;
    write_image_file(coc3, coc, PixelFormat::ExrFloat);
    r = cli("bench bound --clip '" + c.clip.string() + "' --iters 5");
    CHECK(r.code != 0);
    CHECK(r.output.find("clip.json: the wall's blur changes between frames") != std::string::npos);
    // A panning camera and a directory without clip.json.
    TinyClip p = make_tiny("fit_bound_pan", "pan", "64x36");
    r = cli("bench bound --clip '" + p.clip.string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("the camera pans") != std::string::npos);
    r = cli("bench bound --clip '" + p.dir.string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("no clip.json") != std::string::npos);
}

TEST_CASE("radius from the clip as a focal stack matches the ground truth on a focus sweep") {
    TinyClip c = make_tiny("fit_stack_coc", "tripod", "128x72");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    std::vector<float> err;
    double sum_gt = 0;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 4; y < d->height - 4; ++y)
            for (int x = 4; x < d->width - 4; ++x) {
                const float g = gt[t].at(x, y, 0);
                err.push_back(std::abs(d->radius[t][y][x].item<float>() - g));
                sum_gt += g;
            }
    std::sort(err.begin(), err.end());
    const double median = err[err.size() / 2], mean_gt = sum_gt / err.size();
    MESSAGE("focal-stack radius: median abs error " << median << " px (mean true radius " << mean_gt << " px)");
    CHECK(median < 0.35 * mean_gt);
}

TEST_CASE("focal-stack radius on a pan with fixed focus: content entering the frame and a subject never in focus are not read as more blur than they have") {
    // Focus stays on the wall, so no view of any point is sharper than another: relative to its
    // sharpest view every pixel has radius ~0, and what blur there is comes from the floor
    // (edge_blur.h), which must not invent any. Before the canvas covered every frame, content
    // entering the pan was compared with smeared border pixels and read several px of blur; the
    // subject, whose automatic mask holds wall texture, read up to the largest radius tested.
    // At this size (8 frames of 128x72, the wall 0.2-1.5 px) the floor has few edges to go by
    // and overshoots by up to 1.62 px at 1% of the pixels (1.25 while the floor held within 2
    // cells of its edges; it holds within 4 since the sixteenth session, which gained 0.66 dB
    // at 320x180, where the wall's 99th percentile of overshoot stayed 1.99 px).
    TinyClip c = make_tiny("fit_stack_pan", "pan", "128x72");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    std::vector<float> over, over_wall, over_edge;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                const float o = d->radius[t][y][x].item<float>() - gt[t].at(x, y, 0), a = alpha[t].at(x, y, 0);
                over.push_back(o);
                (a < 0.01f ? over_wall : over_edge).push_back(o);
            }
    auto p99_of = [](std::vector<float>& v) { std::sort(v.begin(), v.end()); return v[v.size() * 99 / 100]; };
    const float p99 = p99_of(over);
    MESSAGE("pan: 99th percentile of (estimated - true radius) " << p99 << " px; wall " << p99_of(over_wall) << ", subject " << p99_of(over_edge));
    CHECK(p99 < 1.75f);
}

TEST_CASE("the stack's absolute floor: a wall and a subject never in focus read their blur, not 0") {
    // Synth pan: focus fixed on the far wall, so the stack alone reads ~0 everywhere (above);
    // the truth is 0.4-3.1 px on the wall (by the row) and 5.7 px on the subject at this size.
    // The floor (edge_blur.h: each frame's isolated edges, a robust smooth surface per layer)
    // restores it.
    TinyClip c = make_tiny("fit_stack_floor", "pan", "256x144");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    StackCocOptions relative;
    relative.absolute = false;
    auto rel = estimate_radius_from_stack(*d, relative);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    struct Err {
        double abs_floor = 0, abs_rel = 0, truth = 0;
        int n = 0;
    } wall, subject;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                const float g = gt[t].at(x, y, 0), a = alpha[t].at(x, y, 0);
                Err* e = a > 0.99f ? &subject : (a < 0.01f && g > 1.5f) ? &wall : nullptr;
                if (!e) continue;
                e->abs_floor += std::abs(d->radius[t][y][x].item<float>() - g);
                e->abs_rel += std::abs(rel[t][y][x].item<float>() - g);
                e->truth += g;
                ++e->n;
            }
    REQUIRE(wall.n > 0);
    REQUIRE(subject.n > 0);
    for (Err* e : {&wall, &subject}) {
        e->abs_floor /= e->n;
        e->abs_rel /= e->n;
        e->truth /= e->n;
    }
    MESSAGE("wall (true radius > 1.5 px, mean " << wall.truth << "): mean abs error " << wall.abs_rel
                                                  << " px relative only, " << wall.abs_floor << " with the floor");
    MESSAGE("subject (mean " << subject.truth << "): " << subject.abs_rel << " px relative only, "
                             << subject.abs_floor << " with the floor");
    // 8 frames at this size hold few isolated edges; synth pan at 320x180x30 reads the wall to
    // 0.43-0.62 px and the subject to 0.1-1.2 px (README, "How the fit works" 4).
    CHECK(wall.abs_floor < 0.6 * wall.abs_rel);
    CHECK(subject.abs_floor < 0.6 * subject.abs_rel);
}

TEST_CASE("the stack's absolute floor past what edges measure: a wall blurred 5-9 px is read from tile spectra, without holes") {
    // Synth walkout: focus stays on the subject's first depth, the wall is blurred 9.3 px at the
    // top to 5.3 at the bottom in every frame. Edges read it 30% low (edge_blur.h), so the floor
    // comes from tile spectra (spectral_blur.h): a plane over the tiles' readings, held as a least
    // radius where the stack's relative readings err.
    TinyClip c = make_tiny("fit_stack_spectral", "walkout", "320x180");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto d = build_fit_data(p, {}, log);
    StackCocReport report;
    auto est = estimate_radius_from_stack(*d, {}, &report);
    MESSAGE(report.summary);
    CHECK(report.summary.find("tile spectra") != std::string::npos);
    auto gt = read_all_frames((c.clip / "coc_%04d.exr").string());
    auto alpha = read_all_frames((c.clip / "alpha_%04d.png").string());
    std::vector<float> ratio;
    double abs_err = 0, truth = 0;
    for (int t = 0; t < d->frames; ++t)
        for (int y = 0; y < d->height; ++y)
            for (int x = 0; x < d->width; ++x) {
                if (alpha[t].at(x, y, 0) > 0.01f) continue;
                const float g = gt[t].at(x, y, 0), e = est[t][y][x].item<float>();
                abs_err += std::abs(e - g);
                truth += g;
                ratio.push_back(e / g);
            }
    REQUIRE(!ratio.empty());
    std::sort(ratio.begin(), ratio.end());
    const double p01 = ratio[ratio.size() / 100], p50 = ratio[ratio.size() / 2], p95 = ratio[ratio.size() * 95 / 100],
                 p99 = ratio[ratio.size() * 99 / 100];
    MESSAGE("wall (mean " << truth / ratio.size() << " px): mean abs error " << abs_err / ratio.size()
                          << " px; estimate / truth at the 1st, 50th, 95th, 99th percentile " << p01 << ", " << p50
                          << ", " << p95 << ", " << p99);
    // 8 frames read it to 0.25 px, 30 frames (two layers) to 0.09-0.14 (README, "How the fit works" 4); a radius 15% off the
    // truth at this blur costs more than the whole gain (README, "Known limits").
    CHECK(abs_err / ratio.size() < 0.5);
    CHECK(p50 > 0.93);
    CHECK(p50 < 1.05);
    CHECK(p01 > 0.8);  // no holes where the relative reading alone would have been taken
    // Over: at this size the subject gets no layer of its own (8 frames), and its rim, blurred
    // by up to 6 px, passes over 1-2% of the wall, which the stack reads as blur added.
    CHECK(p95 < 1.15);
}

TEST_CASE("robust weights: a patch no layer can explain does not leak into the shared atlas") {
    // A static one-layer clip whose frame 2 carries a bright square (a flash, a passer-by the
    // masks missed): the atlas is shared, so the square can only be explained in frame 2 at the
    // cost of the other frames. With robust weights the square's pixels soon stop pulling.
    const int64_t T = 6, H = 36, W = 48;
    torch::manual_seed(0);
    auto clean = torch::rand({1, 3, H / 4, W / 4});
    clean = torch::nn::functional::interpolate(
        clean, torch::nn::functional::InterpolateFuncOptions().size(std::vector<int64_t>{H, W})
                   .mode(torch::kBilinear).align_corners(false));
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
        e.apply_fallback(L3, 2, model_sharp);
        CHECK((L3.sharp - L2.sharp - paint).abs().max().item<double>() < 1e-5);
        return diff;
    };
    const double off = leak(0.0), on = leak(1.5);
    MESSAGE("fallback weight of frame 2: patch " << fallback_in << ", left 6 columns at most " << fallback_out);
    CHECK(fallback_in > 0.9);
    CHECK(fallback_out < 0.05);
    MESSAGE("square leaking into frame 0: robust off " << off << ", on " << on);
    CHECK(on < 0.6 * off);
}

TEST_CASE("subject track follows the subject's flow where its masks lose part of it") {
    // A subject moving 1.5 px a frame to the right; frames 2-4 mask only its lower half (a
    // blurred subject's automatic mask loses its head), so their centroids drop 6 px.
    const int T = 7, H = 40, W = 64;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.mask = torch::zeros({T, 1, H, W});
    for (int t = 0; t < T; ++t) {
        const int x0 = 10 + int(std::lround(1.5 * t));
        const bool half = t >= 2 && t <= 4;
        d.mask[t][0].narrow(0, half ? 20 : 8, half ? 12 : 24).narrow(1, x0, 16).fill_(1.0f);
    }
    d.flow_fwd = torch::zeros({T - 1, 2, H, W});
    d.flow_fwd.select(1, 0).fill_(1.5f);  // the subject's motion (the wall's does not matter:
    d.flow_valid = torch::ones({T - 1, 1, H, W});  // only the mask's core is read)
    std::vector<double> vx, vy;
    subject_track(d, vx, vy);
    for (int t = 0; t < T; ++t) {
        CHECK(vx[t] - vx[0] == doctest::Approx(1.5 * t).epsilon(1e-6));
        CHECK(vy[t] - vy[0] == doctest::Approx(0.0).epsilon(1e-6));
    }
    // Anchored on the median centroid: the full masks' centre (y = 19.5), not the halves'.
    CHECK(vy[0] == doctest::Approx(19.5).epsilon(1e-6));
    // Without flow (or for an earlier build's checkpoint) the smoothed centroids, which follow
    // the masks down.
    d.legacy_subject_track = true;
    subject_track(d, vx, vy);
    CHECK(vy[3] > 22.0);
}

// A fast fit of tiny_two_layer_data(seed) with a budget of `iters`, stepped `steps` times and
// checkpointed in the scratch directory `name`.
struct SteppedFit {
    std::shared_ptr<FitData> data;
    FitOptions opts;
    std::unique_ptr<FitEngine> engine;
    fs::path ck;
};
SteppedFit stepped_fit(unsigned seed, int64_t iters, int steps, const std::string& name) {
    SteppedFit f;
    f.data = tiny_two_layer_data(seed);
    f.opts.preset = "fast";
    f.opts.iters = iters;
    f.engine = std::make_unique<FitEngine>(f.data, f.opts);
    for (int i = 0; i < steps; ++i) f.engine->step();
    f.ck = scratch_dir(name);
    f.engine->save_checkpoint(f.ck);
    return f;
}

TEST_CASE("a checkpoint without the shared matte or the track's kind loads as the build that wrote it") {
    SteppedFit f = stepped_fit(5, 4, 2, "fit_old_checkpoint");
    auto& [data, o, engine, ck] = f;
    FitEngine& a = *engine;
    // As an earlier build wrote it: no "subject_track" field.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    CHECK(j.at("subject_track") == "flow-v2");
    j.erase("subject_track");
    write_file_atomic(ck / "checkpoint.json", j.dump());
    auto data_b = std::make_shared<FitData>(*data);
    FitEngine b(data_b, o);
    b.load_checkpoint(ck);
    CHECK(b.data().legacy_subject_track);
    // (Without flow both tracks are the masks' centroids, so the tensors fit either way.)
    CHECK(torch::equal(a.render_frame(1).sharp, b.render_frame(1).sharp));
    // An earlier build's state lacks the shared matte: its per-frame matte is all of alpha.
    auto state = a.model().state();
    auto logits = state.at("alpha_logit").clone();
    state.erase("alpha_atlas");
    b.model().load_state(state);
    auto alpha = b.render_frame(2).alpha;
    auto want = torch::sigmoid(torch::nn::functional::interpolate(
        logits.narrow(0, 2, 1), torch::nn::functional::InterpolateFuncOptions()
                                    .size(std::vector<int64_t>{24, 40})
                                    .mode(torch::kBilinear)
                                    .align_corners(false)));
    CHECK(torch::allclose(alpha, want, 1e-5, 1e-5));
}

TEST_CASE("the fit's kernel: new fits take the pillbox, projects and checkpoints of earlier builds keep the disk") {
    // A checkpoint names its kernel; one without the field was fitted with the paper's disk.
    SteppedFit f = stepped_fit(6, 4, 2, "fit_kernel_checkpoint");
    auto j = nlohmann::json::parse(read_text_file(f.ck / "checkpoint.json"));
    CHECK(j.at("kernel") == "disk");  // tiny_two_layer_data keeps FitData's default
    j.erase("kernel");
    write_file_atomic(f.ck / "checkpoint.json", j.dump());
    {
        FitEngine same(std::make_shared<FitData>(*f.data), f.opts);
        CHECK_NOTHROW(same.load_checkpoint(f.ck));
        CHECK(torch::equal(same.render_frame(1).sharp, f.engine->render_frame(1).sharp));
    }
    auto pillbox = std::make_shared<FitData>(*f.data);
    pillbox->blur = fit_kernel_params("pillbox");
    FitEngine other(pillbox, f.opts);
    try {
        other.load_checkpoint(f.ck);
        FAIL("a disk checkpoint loaded into a pillbox fit");
    } catch (const Error& e) {
        const std::string m = e.what();
        CHECK(m.find("checkpoint.json") != std::string::npos);
        CHECK(m.find("'kernel' is \"disk\"") != std::string::npos);
        CHECK(m.find("pillbox") != std::string::npos);
    }
    CHECK_THROWS_WITH_AS(fit_kernel_params("gauss"), doctest::Contains("unknown kernel 'gauss'"), Error);
    CHECK(fit_kernel_params("pillbox").kernel == BlurKernel::Pillbox);
    CHECK(fit_kernel_params("disk").kernel == BlurKernel::Disk);

    // Settings: fresh ones take the pillbox; a project's "fit" section without a kernel (an
    // earlier build's) reads as the disk; what is written is read back.
    if (!std::getenv("REFOCUS_FIT_KERNEL")) CHECK(FitSettings{}.setup.kernel == "pillbox");
    TinyClip c = make_tiny("fit_kernel_settings");
    Project p = Project::load(c.project);
    FitSettings s;
    s.fit.iters = 3;
    s.setup.kernel = "pillbox";
    write_fit_settings(p, s, nullptr);
    CHECK(read_fit_settings(Project::load(c.project)).setup.kernel == "pillbox");
    auto pj = nlohmann::json::parse(read_text_file(p.project_file()));
    pj.at("fit").erase("kernel");
    write_file_atomic(p.project_file(), pj.dump());
    CHECK(read_fit_settings(Project::load(c.project)).setup.kernel == "disk");
    pj.at("fit")["kernel"] = "bokeh";
    write_file_atomic(p.project_file(), pj.dump());
    CHECK_THROWS_WITH_AS(read_fit_settings(Project::load(c.project)),
                         doctest::Contains("project.json: malformed 'fit' section: fit: unknown kernel 'bokeh'"), Error);
    PrepareLog log;
    FitSetupOptions so;
    so.kernel = "disk";
    CHECK(build_fit_data(Project::load(c.project), so, log)->blur.kernel == BlurKernel::Disk);
    so.kernel = "pillbox";
    CHECK(build_fit_data(Project::load(c.project), so, log)->blur.kernel == BlurKernel::Pillbox);
}

TEST_CASE("a reopened project rebuilds the model its fit trained: the masks are used as stored") {
    // The subject's track and atlas box come from the masks; the fit that prepared them and a
    // later export (which reads them back from 8-bit PNG) must agree to the pixel.
    TinyClip c = make_tiny("fit_reopen_masks", "hunt", "160x90");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto fresh = build_fit_data(p, {}, log);
    auto reused = build_fit_data(p, {}, log);
    REQUIRE(fresh->has_subject == reused->has_subject);
    MESSAGE("tiny hunt clip: " << std::string(fresh->has_subject ? "two layers" : "one layer"));
    if (fresh->has_subject) CHECK(torch::equal(fresh->mask, reused->mask));
    auto a = make_model("fast", *fresh, 1), b = make_model("fast", *reused, 1);
    CHECK(a->atlas_bg().sizes() == b->atlas_bg().sizes());
    if (fresh->has_subject) {
        CHECK(a->atlas_fg().sizes() == b->atlas_fg().sizes());
        CHECK(torch::equal(a->state().at("alpha_atlas"), b->state().at("alpha_atlas")));
    }
}

TEST_CASE("subject track: a subject walking away is followed in size as well") {
    // A square subject centred at (40, 30) shrinking by 10% a frame; the flow is the expansion
    // about that centre (everywhere: only the mask's core is read).
    const int T = 5, H = 64, W = 80;
    const double cx = 40, cy = 30, k = 0.9;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.mask = torch::zeros({T, 1, H, W});
    for (int t = 0; t < T; ++t) {
        const int half = int(std::lround(24 * std::pow(k, t)));
        d.mask[t][0].narrow(0, int(cy) - half, 2 * half).narrow(1, int(cx) - half, 2 * half).fill_(1.0f);
    }
    auto g = torch::meshgrid({torch::arange(H, torch::kFloat32), torch::arange(W, torch::kFloat32)}, "ij");
    d.flow_fwd = torch::stack({(k - 1) * (g[1] - cx), (k - 1) * (g[0] - cy)}).unsqueeze(0).repeat({T - 1, 1, 1, 1});
    d.flow_valid = torch::ones({T - 1, 1, H, W});
    std::vector<double> vx, vy, sc;
    subject_track(d, vx, vy, &sc);
    for (int t = 0; t < T; ++t) {
        CHECK(sc[t] == doctest::Approx(std::pow(k, t)).epsilon(1e-3));
        // The subject's centre and a corner land on the same track coordinates in every frame.
        const double corner = 20 * std::pow(k, t);
        auto m = subject_to_track(vx[t], vy[t], sc[t]);
        auto c = torch::matmul(m, torch::tensor({cx, cy, 1.0}, torch::kFloat64));
        auto e = torch::matmul(m, torch::tensor({cx + corner, cy - corner, 1.0}, torch::kFloat64));
        auto m0 = subject_to_track(vx[0], vy[0], sc[0]);
        auto c0 = torch::matmul(m0, torch::tensor({cx, cy, 1.0}, torch::kFloat64));
        auto e0 = torch::matmul(m0, torch::tensor({cx + 20, cy - 20, 1.0}, torch::kFloat64));
        CHECK((c - c0).abs().max().item<double>() < 0.05);
        CHECK((e - e0).abs().max().item<double>() < 0.05);
    }
    // A subject of one size keeps scale 1 (the translation track, bit for bit).
    d.flow_fwd.zero_();
    for (int t = 0; t < T; ++t) d.mask[t] = d.mask[0];
    subject_track(d, vx, vy, &sc);
    for (double s : sc) CHECK(s == 1.0);
}

// Each layer's radius split (split_radius_by_layer) over a wall whose radius ramps from 1 px by
// `slope` px per column (`ramp` receives it), with a subject of radius `r` in frame 0's box
// `subject` and frame 0's mask in box `mask` (boxes: row, rows, column, columns).
static FitData split_over_ramp(int frames, int height, int width, double slope,
                               std::array<int, 4> subject, float r, std::array<int, 4> mask,
                               torch::Tensor& ramp) {
    FitData d;
    d.frames = frames, d.height = height, d.width = width;
    d.has_subject = true;
    ramp = (1.0 + torch::arange(width, torch::kFloat32) * slope).view({1, 1, width}).expand({frames, height, width});
    d.radius = ramp.clone();
    d.radius[0].narrow(0, subject[0], subject[1]).narrow(1, subject[2], subject[3]).fill_(r);
    d.mask = torch::zeros({frames, 1, height, width});
    d.mask[0].narrow(1, mask[0], mask[1]).narrow(2, mask[2], mask[3]).fill_(1.0);
    split_radius_by_layer(d);
    return d;
}

TEST_CASE("each layer's radius: the subject's spreads past its silhouette, the wall's continues behind it") {
    // Two frames 40x30: a 12x10 subject at radius 5 in front of a wall whose radius ramps
    // 1 → 2.45 px left to right; frame 1 has no subject.
    torch::Tensor ramp;
    FitData d = split_over_ramp(2, 30, 40, 0.0375, {10, 10, 14, 12}, 5.0f, {10, 10, 14, 12}, ramp);
    REQUIRE(d.radius_fg.defined());
    REQUIRE(d.radius_bg.defined());
    // Where each layer is sure (2 px inside its own region) it keeps the map as given.
    CHECK(torch::allclose(d.radius_fg[0].narrow(0, 12, 6).narrow(1, 16, 8), torch::full({6, 8}, 5.0f)));
    CHECK(torch::allclose(d.radius_bg[0].narrow(0, 0, 8), ramp[0].narrow(0, 0, 8)));
    // The subject's radius reaches past its edge (its blurred edge scatters over the wall).
    CHECK(d.radius_fg[0][15][10].item<float>() == doctest::Approx(5.0).epsilon(0.02));
    CHECK(d.radius_fg[0][5][20].item<float>() == doctest::Approx(5.0).epsilon(0.02));
    // Behind the subject the wall keeps the wall's radius, within its ramp's range there.
    auto behind = d.radius_bg[0].narrow(0, 10, 10).narrow(1, 14, 12);
    CHECK(behind.min().item<float>() > 1.4f);
    CHECK(behind.max().item<float>() < 2.1f);
    // A frame without the subject keeps the map for both layers.
    CHECK(torch::equal(d.radius_fg[1], d.radius[1]));
    CHECK(torch::equal(d.radius_bg[1], d.radius[1]));
    // One layer: nothing split.
    d.mask = torch::Tensor();
    split_radius_by_layer(d);
    CHECK_FALSE(d.radius_fg.defined());
    CHECK(d.layer_radius(true).data_ptr() == d.radius.data_ptr());
}

TEST_CASE("each layer's radius from a blob of a mask: the rim keeps the subject's radius, a missed part the wall's") {
    // One frame 60x50: a 16x15 subject at radius 6 (rows 15-29, columns 20-35) in front of a wall
    // whose radius ramps 1 -> 2.5 px left to right. Its automatic mask is a blob 3 px wider on
    // top, left and right (wall pixels, the wall's radius) that misses its bottom 4 rows.
    torch::Tensor ramp;
    FitData d = split_over_ramp(1, 50, 60, 0.025, {15, 15, 20, 16}, 6.0f, {12, 14, 17, 23}, ramp);
    REQUIRE(d.radius_fg.defined());
    // The mask's rim holds the wall's radius; the subject's layer takes the subject's there.
    CHECK(d.radius_fg[0][13][18].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    CHECK(d.radius_fg[0][20][38].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    CHECK(d.radius_fg[0][20][28].item<float>() == doctest::Approx(6.0).epsilon(0.02));
    // The part the mask missed holds the subject's radius; the wall's layer keeps the wall's.
    auto missed = d.radius_bg[0].narrow(0, 28, 2).narrow(1, 20, 16);
    CHECK(missed.max().item<float>() < 2.6f);
    CHECK(missed.min().item<float>() > 1.0f);
    // Far from the subject the wall's map is as given.
    CHECK(torch::allclose(d.radius_bg[0].narrow(0, 40, 10), ramp[0].narrow(0, 40, 10)));
}

TEST_CASE("a checkpoint keeps its atlases' geometry: a build that would place them otherwise renders what was trained") {
    SteppedFit f = stepped_fit(7, 6, 3, "fit_geometry_checkpoint");
    auto& [data, o, engine, ck] = f;
    FitEngine& a = *engine;
    // The same clip whose masks now say the subject is wider and lower: this build computes
    // another foreground box and track for it.
    auto data_b = std::make_shared<FitData>(*data);
    data_b->mask = torch::zeros_like(data->mask);
    data_b->mask.narrow(2, 11, 10).narrow(3, 9, 16).fill_(1.0f);
    FitEngine b(data_b, o);
    REQUIRE_FALSE(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    b.load_checkpoint(ck);
    CHECK(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    CHECK(torch::equal(a.render_frame(2).sharp, b.render_frame(2).sharp));
    CHECK(torch::equal(a.render_frame(2).alpha, b.render_frame(2).alpha));
    // Training goes on from there (the optimiser follows the adopted tensors; its masks differ,
    // so its bootstrap term does too).
    b.step();
    CHECK(std::isfinite(b.snapshot().loss));
    CHECK(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    // An eighth-session checkpoint ("flow": masks as stored, no cleaning) rebuilds from them.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    j["subject_track"] = "flow";
    write_file_atomic(ck / "checkpoint.json", j.dump());
    auto data_c = std::make_shared<FitData>(*data_b);
    data_c->mask_as_stored = data->mask.clone();
    FitEngine c(data_c, o);
    c.load_checkpoint(ck);
    CHECK(c.data().legacy_track_gaps);
    CHECK_FALSE(c.data().legacy_subject_track);
    CHECK(torch::equal(c.data().mask, data->mask));
    CHECK(torch::equal(a.render_frame(2).sharp, c.render_frame(2).sharp));
    // A geometry that does not fit the clip is refused with the tensor named.
    auto state = a.model().state();
    state["fg_to_atlas"] = torch::eye(3).expand({2, 3, 3}).clone();
    CHECK_THROWS_WITH_AS(b.model().load_state(state), doctest::Contains("fg atlas"), Error);
}

TEST_CASE("automatic masks cleaned along the subject's track: a passing blob is dropped, a lost frame refilled") {
    // A 12x12 subject moving 2 px a frame to the right over 8 frames of 80x40 (flow to match).
    // Frame 3's mask also holds a wall tile; frame 5's lost the subject.
    FitData d;
    d.frames = 8, d.height = 40, d.width = 80;
    d.has_subject = true;
    d.input = torch::zeros({8, 3, 40, 80});
    d.radius = torch::zeros({8, 40, 80});
    d.to_ref = torch::eye(3, torch::kFloat64).expand({8, 3, 3}).clone();
    d.flow_fwd = torch::zeros({7, 2, 40, 80});
    d.flow_fwd.select(1, 0).fill_(2.0f);
    d.flow_valid = torch::ones({7, 1, 40, 80});
    d.mask = torch::zeros({8, 1, 40, 80});
    for (int t = 0; t < 8; ++t)
        if (t != 5) d.mask[t][0].narrow(0, 14, 12).narrow(1, 10 + 2 * t, 12).fill_(1.0f);
    d.mask[3][0].narrow(0, 0, 8).narrow(1, 60, 14).fill_(1.0f);
    auto want = d.mask.clone();
    want[3][0].narrow(0, 0, 8).narrow(1, 60, 14).zero_();
    want[5][0].narrow(0, 14, 12).narrow(1, 20, 12).fill_(1.0f);
    const std::string line = clean_subject_masks(d);
    MESSAGE(line);
    CHECK(line.find("1 part(s)") != std::string::npos);
    CHECK(line.find("1 frame(s)") != std::string::npos);
    CHECK((d.mask > 0.5).eq(want > 0.5).all().item<bool>());
    // A subject leaving the frame is not put back: its mask shrinks as the moved one would.
    FitData e = d;
    e.mask = torch::zeros({8, 1, 40, 80});
    for (int t = 0; t < 8; ++t) {
        const int x0 = 50 + 4 * t, x1 = std::min(80, x0 + 12);
        if (x1 > x0) e.mask[t][0].narrow(0, 14, 12).narrow(1, x0, x1 - x0).fill_(1.0f);
    }
    e.flow_fwd.select(1, 0).fill_(4.0f);
    auto before = e.mask.clone();
    clean_subject_masks(e);
    CHECK(torch::equal(e.mask > 0.5, before > 0.5));
}

TEST_CASE("a static camera's hand shake is found; a locked-off camera keeps the identity") {
    // Prepare calls a camera static when its feature homographies move the corners < 2 px, and
    // the fit then maps frames by the identity. A hand-held shot shakes by a pixel (synth walkout:
    // 1.5 px, which cost it 0.4 dB); the ECC pass against the reblurred atlas finds the shake.
    const int64_t T = 5, H = 48, W = 64;
    torch::manual_seed(4);
    namespace F = torch::nn::functional;
    auto texture = F::interpolate(torch::rand({1, 3, H / 3, W / 3}),
                                  F::InterpolateFuncOptions().size(std::vector<int64_t>{H + 16, W + 16})
                                      .mode(torch::kBilinear).align_corners(false));
    const double sx[T] = {0.0, 0.9, -1.2, 0.5, 1.4}, sy[T] = {0.0, -0.6, 0.8, 1.1, -0.4};
    auto make = [&](bool shake) {
        auto d = std::make_shared<FitData>();
        d->frames = T, d->height = H, d->width = W;
        std::vector<torch::Tensor> frames;
        for (int64_t t = 0; t < T; ++t) {
            // Frame pixel (x, y) shows the texture at (x + 8 + sx, y + 8 + sy).
            const double dx = shake ? sx[t] : 0.0, dy = shake ? sy[t] : 0.0;
            auto ys = (torch::arange(H, torch::kFloat32) + 8.0 + dy + 0.5) * (2.0 / (H + 16)) - 1.0;
            auto xs = (torch::arange(W, torch::kFloat32) + 8.0 + dx + 0.5) * (2.0 / (W + 16)) - 1.0;
            auto g = torch::meshgrid({ys, xs}, "ij");
            auto grid = torch::stack({g[1], g[0]}, -1).unsqueeze(0);
            auto f = F::grid_sample(texture, grid, F::GridSampleFuncOptions().mode(torch::kBilinear)
                                                       .align_corners(false))[0];
            frames.push_back(lens_blur(f.contiguous(), torch::full({H, W}, 1.0f), d->blur));
        }
        d->input = torch::stack(frames);
        d->radius = torch::full({T, H, W}, 1.0f);
        d->to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
        d->static_camera = true;
        return d;
    };
    FastModelOptions o;
    {
        auto d = make(true);
        FastModel m(*d, o);
        auto A = m.state().at("bg_to_atlas");
        for (int64_t t = 1; t < T; ++t) {
            const double ex = A[t][0][2].item<double>() - A[0][0][2].item<double>();
            const double ey = A[t][1][2].item<double>() - A[0][1][2].item<double>();
            INFO("frame " << t << ": found (" << ex << ", " << ey << "), shaken by (" << sx[t] << ", " << sy[t] << ")");
            CHECK(std::abs(ex - sx[t]) < 0.15);
            CHECK(std::abs(ey - sy[t]) < 0.15);
        }
    }
    {
        auto d = make(false);
        FastModel m(*d, o);
        auto A = m.state().at("bg_to_atlas");
        CHECK(torch::equal(A, A[0].expand_as(A)));  // exactly the identity (up to the atlas origin)
        CHECK(A[0][0][0].item<double>() == 1.0);
        CHECK(A[0][0][1].item<double>() == 0.0);
    }
}

namespace {
// A pan over a texture with detail up to the frame's Nyquist limit, each frame box-filtered
// from a 4x render (a sensor integrates over its pixel): frame t shows the texture moved by
// `pan` px per frame, at a new sub-pixel phase each time. Returns the data and the sharp frames.
std::pair<std::shared_ptr<FitData>, torch::Tensor> pan_over_detail(int64_t T, double pan, double radius) {
    namespace F = torch::nn::functional;
    const int64_t H = 40, W = 56, S = 4, M = 24;  // M: texture margin, px
    torch::manual_seed(11);
    // Texture at 4x: random 1.5 px cells, nearest-neighbour (hard edges, as glyphs and checkers).
    auto cells = torch::rand({1, 3, (H + 2 * M) * 2 / 3, (W + 2 * M) * 2 / 3});
    auto tex = F::interpolate(cells, F::InterpolateFuncOptions()
                                         .size(std::vector<int64_t>{(H + 2 * M) * S, (W + 2 * M) * S})
                                         .mode(torch::kNearest));
    auto d = std::make_shared<FitData>();
    d->frames = T, d->height = H, d->width = W;
    d->blur.kernel = BlurKernel::Pillbox;
    std::vector<torch::Tensor> sharp, in, hs;
    for (int64_t t = 0; t < T; ++t) {
        const double dx = pan * t;  // frame pixel x shows the texture at x + M + dx
        const int64_t ox = int64_t(std::floor(dx * S)), oy = M * S;
        auto crop = tex.narrow(2, oy, H * S).narrow(3, M * S + ox, W * S);
        auto f = F::avg_pool2d(crop, F::AvgPool2dFuncOptions(S))[0];  // exact for dx on the 1/4 grid
        sharp.push_back(f);
        in.push_back(lens_blur(f.contiguous(), torch::full({H, W}, float(radius)), d->blur));
        hs.push_back(translation(double(ox) / S, 0.0));  // frame t → frame 0's coordinates
    }
    d->input = torch::stack(in);
    d->radius = torch::full({T, H, W}, float(radius));
    d->to_ref = torch::stack(hs).to(torch::kFloat64);
    d->static_camera = false;
    return {d, torch::stack(sharp)};
}

double psnr_of(const torch::Tensor& a, const torch::Tensor& b) {
    return 10 * std::log10(1.0 / (a - b).pow(2).mean().item<double>());
}
}  // namespace

TEST_CASE("a moving camera fits a 2x atlas: detail seen at many sub-pixel phases is resolved; checkpoints keep the resolution") {
    auto [d, sharp] = pan_over_detail(8, 1.25, 0.4);
    // The decision: a given radius, a moving camera and the clip in focus take 2x; an estimated
    // radius, a static camera, or a clip that nothing shows in focus stay at the frame's
    // resolution.
    CHECK(choose_atlas_scale(*d, true).find("2x") != std::string::npos);
    CHECK(d->atlas_scale == 2);
    {
        FitData s = *d;
        s.static_camera = true;
        choose_atlas_scale(s, true);
        CHECK(s.atlas_scale == 1);
        s = *d;
        s.radius = torch::full_like(d->radius, 4.0f);
        CHECK(choose_atlas_scale(s, true).find("1x") != std::string::npos);
        CHECK(s.atlas_scale == 1);
        s = *d;  // an estimated radius: its errors would be fitted too
        CHECK(choose_atlas_scale(s, false).find("estimated") != std::string::npos);
        CHECK(s.atlas_scale == 1);
        s = *d;  // ... unless focus never changed: the floor, one surface that all frames share
        s.fixed_focus_share = 0.95;
        CHECK(choose_atlas_scale(s, false).find("2x") != std::string::npos);
        CHECK(s.atlas_scale == 2);
    }
    // Texels sit on the frame's pixel centres: the initial (fused) atlas renders each frame back
    // in place, at 2x as closely as at 1x.
    auto fused_err = [&](double scale) {
        FastModelOptions o;
        o.atlas_scale = scale;
        o.align_rounds = 0;
        FastModel m(*d, o);
        torch::NoGradGuard g;
        auto r = m.render({0, 3, 7}).sharp;
        return psnr_of(r, d->input.index_select(0, torch::tensor({0, 3, 7})));
    };
    const double p1 = fused_err(1), p2 = fused_err(2);
    MESSAGE("fused atlas rendered back: 1x " << p1 << " dB, 2x " << p2 << " dB");
    CHECK(p2 > p1 - 0.5);
    CHECK(p2 > 28.0);
    // Fitted: the 2x atlas reproduces the sharp frames better.
    auto fit = [&](double scale, const fs::path& ck) {
        auto data = std::make_shared<FitData>(*d);
        data->atlas_scale = scale;
        FitOptions o;
        o.preset = "fast";
        o.iters = 200;
        FitEngine e(data, o);
        while (!e.done()) e.step();
        std::vector<torch::Tensor> out;
        for (int t = 0; t < data->frames; ++t) out.push_back(e.render_frame(t).sharp[0]);
        if (!ck.empty()) e.save_checkpoint(ck);
        return psnr_of(torch::stack(out).clamp(0, 1), sharp);
    };
    const fs::path ck = scratch_dir("fit_atlas_scale");
    const double f1 = fit(1, {}), f2 = fit(2, ck);
    MESSAGE("fitted, sharp PSNR: input " << psnr_of(d->input, sharp) << " dB, 1x " << f1 << ", 2x " << f2);
    CHECK(f2 > f1 + 1.0);
    // The checkpoint names its scale; a reopened project takes it whatever this build decides,
    // and a checkpoint of an earlier build (no field) was 1x.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    CHECK(j.at("atlas_scale") == 2.0);
    auto reopened = std::make_shared<FitData>(*d);
    reopened->atlas_scale = 1;
    FitOptions o;
    o.preset = "fast";
    o.iters = 200;
    FitEngine e(reopened, o);
    e.load_checkpoint(ck);
    CHECK(e.data().atlas_scale == 2);
    CHECK(e.model().atlas_bg().size(2) > 2 * d->width);
    j.erase("atlas_scale");
    write_file_atomic(ck / "checkpoint.json", j.dump());
    FitEngine old(std::make_shared<FitData>(*d), o);  // this build decides 2x
    old.load_checkpoint(ck);
    CHECK(old.data().atlas_scale == 1);
}

TEST_CASE("the deblurring path: a wall blurred in every frame deblurs faster; it leaves the mean; old checkpoints load") {
    // A static wall of hard-edged cells seen by 6 frames, each blurred 4 px (8-bit), as a wall
    // that focus never reached. Adam moves each texel by about its learning rate, so the detail
    // the pillbox passed at a few percent comes back slowly through the texels alone; through
    // the path's filter it does not (synth walkout, true radius, 600 steps: 20.15 -> 21.51 dB).
    auto [d, sharp] = pan_over_detail(6, 0.0, 4.0);
    {
        namespace F = torch::nn::functional;
        torch::manual_seed(5);  // cells of 4 px: what a 4 px blur leaves of them can come back
        auto wall = F::interpolate(torch::rand({1, 3, d->height / 4, d->width / 4}),
                                   F::InterpolateFuncOptions().size(std::vector<int64_t>{d->height, d->width})
                                       .mode(torch::kNearest))[0];
        auto in = lens_blur(wall.contiguous(), d->radius[0].contiguous(), d->blur);
        sharp = wall.unsqueeze(0).expand({d->frames, 3, d->height, d->width}).contiguous();
        d->input = ((in * 255.0).round() / 255.0).unsqueeze(0).expand_as(sharp).contiguous();
    }
    d->static_camera = true;
    auto fit = [&, &d = d, &sharp = sharp](bool path) {
        setenv("REFOCUS_FAST_DEBLUR_PATH", path ? "1" : "0", 1);
        FitOptions o;
        o.preset = "fast";
        o.iters = 400;
        o.batch = 2;  // the same frames a step with and without: the path is what is compared
        FitEngine e(std::make_shared<FitData>(*d), o);
        unsetenv("REFOCUS_FAST_DEBLUR_PATH");
        const bool has = e.model().state().count("bg_deblur") > 0;
        CHECK(has == path);
        CHECK(e.batch() == 2);
        if (path) {
            REQUIRE(e.model_notes().size() == 1);
            CHECK(e.model_notes()[0].find("median sharpest radius 4.0 px") != std::string::npos);
        }
        while (!e.done()) e.step();
        std::vector<torch::Tensor> out;
        for (int t = 0; t < d->frames; ++t) out.push_back(e.render_frame(t).sharp[0]);
        return psnr_of(torch::stack(out).clamp(0, 1), sharp);
    };
    const double off = fit(false), on = fit(true);
    MESSAGE("400 steps, sharp PSNR: input " << psnr_of(d->input, sharp) << " dB, texels alone " << off
                                            << ", with the path " << on);
    CHECK(on > off + 1.0);
    {
        // Left to the model, a fit with the path takes 4 frames a step and says so; without, 2.
        FitOptions o;
        o.preset = "fast";
        o.iters = 1;
        FitEngine with(std::make_shared<FitData>(*d), o);
        CHECK(with.batch() == 4);
        REQUIRE(with.model_notes().size() == 2);
        CHECK(with.model_notes()[1].find("4 frames a step") != std::string::npos);
        setenv("REFOCUS_FAST_DEBLUR_PATH", "0", 1);
        FitEngine without(std::make_shared<FitData>(*d), o);
        unsetenv("REFOCUS_FAST_DEBLUR_PATH");
        CHECK(without.batch() == 2);
        CHECK(without.model_notes().empty());
    }

    FastModelOptions o;
    o.align_rounds = 0;
    FastModel m(*d, o);
    auto s = m.state();
    REQUIRE(s.count("bg_deblur"));
    {
        // The path adds detail only: a constant through it leaves the atlas as it was.
        torch::NoGradGuard g;
        auto before = m.atlas_bg();
        s.at("bg_deblur").fill_(0.25);
        CHECK((m.atlas_bg() - before).abs().max().item<double>() < 1e-4);
    }
    // A checkpoint of an earlier build has no path: its texels hold the whole atlas.
    std::map<std::string, torch::Tensor> old;
    for (auto& [k, v] : s)
        if (k != "bg_deblur") old[k] = v.detach().clone();
    FastModel n(*d, o);
    n.load_state(old);
    CHECK(n.state().at("bg_deblur").abs().max().item<double>() == 0.0);
    // A blur under the threshold gets no path.
    auto [sharp_d, unused] = pan_over_detail(3, 0.0, 1.0);
    FastModel few(*sharp_d, o);
    CHECK(few.state().count("bg_deblur") == 0);
    CHECK(few.notes.at(0).find("no deblurring path") != std::string::npos);
}

TEST_CASE("MS-SSIM loss: the fused Gaussian filter matches the tensor-op reference, value and gradient") {
    torch::manual_seed(7);
    SUBCASE("the filter: an impulse gives the 11x11 window, a constant stays, the adjoint is exact") {
        auto x = torch::zeros({1, 1, 21, 23}, torch::kDouble);
        x[0][0][10][11] = 1.0;
        auto y = gauss_filter_valid(x);
        REQUIRE(y.sizes() == torch::IntArrayRef({1, 1, 11, 13}));
        CHECK(y.sum().item<double>() == doctest::Approx(1.0).epsilon(1e-12));
        CHECK(torch::allclose(y, gauss_filter_valid_reference(x), 0, 1e-15));
        const double g5 = y[0][0][5][6].item<double>(), g0 = y[0][0][0][1].item<double>();
        CHECK(g5 > 0.07);  // the centre tap squared: (1 / Σ exp(−i²/4.5))²
        CHECK(g0 == doctest::Approx(g5 * std::exp(-25.0 / 4.5) * std::exp(-25.0 / 4.5)).epsilon(1e-9));
        auto c = torch::full({2, 3, 15, 17}, 0.25, torch::kDouble);
        CHECK(torch::allclose(gauss_filter_valid(c), torch::full({2, 3, 5, 7}, 0.25, torch::kDouble)));
        // <G x, v> = <x, Gᵀ v>, with Gᵀ from the custom backward.
        auto a = torch::rand({2, 2, 30, 41}, torch::kDouble).requires_grad_(true);
        auto v = torch::rand({2, 2, 20, 31}, torch::kDouble);
        auto lhs = (gauss_filter_valid(a) * v).sum();
        lhs.backward();
        CHECK((a.grad() * a).sum().item<double>() == doctest::Approx(lhs.item<double>()).epsilon(1e-12));
        CHECK_THROWS_AS(gauss_filter_valid(torch::rand({1, 1, 10, 40})), Error);
    }
    SUBCASE("the loss, float as trained, 5 and 3 scales, gradients to both images") {
        for (auto hw : {std::array<int64_t, 2>{180, 200}, std::array<int64_t, 2>{48, 70}}) {
            auto b0 = torch::rand({2, 3, hw[0], hw[1]});
            auto a0 = (b0 + 0.2 * torch::randn({2, 3, hw[0], hw[1]})).clamp(0, 1);
            auto a = a0.clone().requires_grad_(true), b = b0.clone().requires_grad_(true);
            auto fast = ms_ssim_loss(a, b);
            fast.backward();
            auto ga = a.grad().clone(), gb = b.grad().clone();
            a.mutable_grad().zero_();
            b.mutable_grad().zero_();
            auto ref = ms_ssim_loss_reference(a, b);
            ref.backward();
            INFO("size " << hw[0] << "x" << hw[1]);
            CHECK(fast.item<double>() > 0.05);
            CHECK(fast.item<double>() == doctest::Approx(ref.item<double>()).epsilon(1e-5));
            const double scale = a.grad().abs().max().item<double>();
            CHECK(scale > 0);
            CHECK((ga - a.grad()).abs().max().item<double>() < 1e-4 * scale);
            CHECK((gb - b.grad()).abs().max().item<double>() < 1e-4 * scale);
            CHECK(ms_ssim_loss(b0, b0).item<double>() == doctest::Approx(0.0).epsilon(1e-6));
        }
    }
}

TEST_CASE("weighted TV: each difference weighs its two pixels' mean weight, broadcast over channels") {
    auto x = torch::rand({1, 3, 9, 12}, torch::kDouble);
    CHECK(tv_l1(x, torch::ones({1, 1, 9, 12}, torch::kDouble)).item<double>() ==
          doctest::Approx(tv_l1(x).item<double>()).epsilon(1e-12));
    CHECK(tv_l1(x, torch::full({1, 1, 9, 12}, 3.0, torch::kDouble)).item<double>() ==
          doctest::Approx(3 * tv_l1(x).item<double>()).epsilon(1e-12));
    // A ramp along x (step 1 per px) under a weight of 1 on the left half and 3 on the right:
    // the difference across the boundary weighs 2.
    auto ramp = torch::arange(4, torch::kDouble).view({1, 1, 1, 4}).expand({1, 1, 2, 4}).contiguous();
    auto w = torch::tensor({1.0, 1.0, 3.0, 3.0}, torch::kDouble).view({1, 1, 1, 4}).expand({1, 1, 2, 4});
    CHECK(tv_l1(ramp, w).item<double>() == doctest::Approx((1.0 + 2.0 + 3.0) / 3.0).epsilon(1e-12));
}

TEST_CASE("TV by the radii a texel was seen at: one radius in every view weighs more, a focus change does not") {
    // Texels: seen at 3 px in every view; at 0.5 px everywhere; sharpest 0.2 px but over 0.2..6 px
    // (a focus pull); at 9 px everywhere (capped); at 2 px with a spread of 0.5 px (half-way).
    auto sharp = torch::tensor({3.0, 0.5, 0.2, 9.0, 2.0}, torch::kDouble);
    auto mean = torch::tensor({3.0, 0.5, 3.0, 9.0, 2.0}, torch::kDouble);
    auto sd = torch::tensor({0.0, 0.0, 2.0, 0.0, 0.5}, torch::kDouble);
    auto f = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 1.0, 4.0, 1.0);
    CHECK(f[0].item<double>() == doctest::Approx(3.0));
    CHECK(f[1].item<double>() == doctest::Approx(1.0));
    CHECK(f[2].item<double>() == doctest::Approx(1.0));
    CHECK(f[3].item<double>() == doctest::Approx(4.0));
    CHECK(f[4].item<double>() == doctest::Approx(1.5));
    auto g2 = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 2.0, 4.0, 1.0);
    CHECK(g2[1].item<double>() == doctest::Approx(1.0));
    CHECK(g2[0].item<double>() == doctest::Approx(4.0));
    CHECK(tv_radius_factor(sharp, mean, mean * mean, 1.0, 1.0, 1.0).eq(1.0).all().item<bool>());
    // Deep blur fades back to 1: 9 px is past a fade at 5; 3 px is not; 4.5 px is half-way.
    auto faded = tv_radius_factor(sharp, mean, mean * mean + sd * sd, 1.0, 4.0, 1.0, 5.0);
    CHECK(faded[0].item<double>() == doctest::Approx(3.0));
    CHECK(faded[3].item<double>() == doctest::Approx(1.0));
    auto half = tv_radius_factor(torch::full({1}, 4.5, torch::kDouble), torch::full({1}, 4.5, torch::kDouble),
                                 torch::full({1}, 4.5 * 4.5, torch::kDouble), 1.0, 4.0, 1.0, 5.0);
    CHECK(half[0].item<double>() == doctest::Approx(1.0 + 3.0 * 0.5));
}

TEST_CASE("the stack's wall behind a sharp subject that walked off: seen blurred, it keeps its floor") {
    // A wall of flat blocks blurred 3 px (never in focus) and a sharp, high-contrast subject
    // crossing it. The wall's composite weighs its own views against the sharpest of them; against
    // every view's, the points the subject had covered kept weights of (contrast ratio)^8 ~ 0
    // there, counted as never seen, and kept no floor: holes of radius 0 in every later frame
    // (synth walkout: 27% of a 20x40 px block read 0-0.6 px for 6 px).
    const int T = 8, H = 64, W = 96;
    torch::manual_seed(5);
    LensBlurParams bp;
    bp.kernel = BlurKernel::Pillbox;
    auto blocks = torch::rand({3, H / 8, W / 8}) * 0.3 + 0.3;
    auto wall = lens_blur(torch::repeat_interleave(torch::repeat_interleave(blocks, 8, 1), 8, 2).contiguous(),
                          torch::full({H, W}, 3.0f), bp);
    auto ys = torch::arange(H).view({H, 1}), xs = torch::arange(W).view({1, W});
    auto checker = ((ys / 2 + xs / 2) % 2).to(torch::kFloat32).expand({3, H, W}) * 0.95 + 0.02;
    FitData d;
    d.frames = T, d.height = H, d.width = W;
    d.blur = bp;
    std::vector<torch::Tensor> frames, masks;
    for (int t = 0; t < T; ++t) {
        const int x0 = 6 + 8 * t;  // 24x24, 8 px a frame
        auto m = ((ys >= 20) & (ys < 44) & (xs >= x0) & (xs < x0 + 24)).to(torch::kFloat32).view({1, H, W});
        auto subject = torch::roll(checker, {8 * t}, {2});  // its texture moves with it
        frames.push_back(m * subject + (1 - m) * wall);
        masks.push_back(m);
    }
    d.input = torch::stack(frames).contiguous();
    d.mask = torch::stack(masks).contiguous();
    d.has_subject = true;
    d.to_ref = torch::eye(3, torch::kFloat64).expand({T, 3, 3}).contiguous();
    auto est = estimate_radius_from_stack(d);
    // The last frame's wall where the subject stood in the first (x 6-29, clear of it by then).
    auto seen_later = est[T - 1].narrow(0, 24, 16).narrow(1, 8, 20);
    auto elsewhere = est[T - 1].narrow(0, 4, 12).narrow(1, 8, 80);
    MESSAGE("wall behind the subject's first place: " << seen_later.mean().item<float>() << " px (min "
            << seen_later.min().item<float>() << "); elsewhere " << elsewhere.mean().item<float>() << " px; truth 3");
    CHECK(seen_later.min().item<float>() > 0.6f * elsewhere.mean().item<float>());
}
