// The `refocus bench ...` commands on tiny generated clips: bench fit and bench bound.
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "io/image_file.h"
#include "session/fit_session.h"
#include "project/project.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE(
    "bench fit prints run time against error and writes the CSV; --batch reaches the engine") {
    TinyClip c = make_tiny("fit_bench");
    const fs::path csv = c.dir / "bench.csv", work = c.dir / "bench_work";
    RunResult r = cli("bench fit --clip '" + c.clip.string() +
                      "' --preset fast --iters 12 --at 0,0.0001 --batch 3 "
                      "--oracle-coc --csv '" +
                      csv.string() + "' --work '" + work.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("radius ground truth") != std::string::npos);
    CHECK(r.output.find("(end)") != std::string::npos);
    CHECK(r.output.find("gain over input") != std::string::npos);
    // The end's error by spatial frequency: every band from 0 to 0.71 cycles/px, the input's
    // beside.
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

TEST_CASE("bench bound: the wall's ceiling and Wiener bound against the truth; bad clips refused") {
    TinyClip c = make_tiny("fit_bound", "walkout", "160x90");
    // A fit's sharp frames are scored on the same pixels: the truth itself scores far above all.
    RunResult r = cli("bench bound --clip '" + c.clip.string() +
                      "' --lambdas 1e-6,1e-5 --iters 60 --sharp '" + c.clip.string() + "'");
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
