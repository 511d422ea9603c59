// Flow from the mappings (edit/uv_flow.h, [paper] §5.2): exact on known mappings, each pixel by
// its layer, a pixel leaving the frame included; and `export --what flow` against a synth
// clip's true flow.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

#include "edit/uv_flow.h"
#include "io/image_file.h"
#include "synth/synth.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// [1,H,W,2] atlas coordinates of an affine mapping: u = a·(x - dx) + b·(y - dy), ...
torch::Tensor affine_uv(int h, int w, double dx, double dy, double rot) {
    auto uv = torch::zeros({1, h, w, 2});
    auto p = uv.accessor<float, 4>();
    const double c = std::cos(rot), s = std::sin(rot);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const double X = x - dx, Y = y - dy;
            p[0][y][x][0] = float((c * X - s * Y) / 50.0 - 0.5);
            p[0][y][x][1] = float((s * X + c * Y) / 40.0 - 0.3);
        }
    return uv;
}

// A flow EXR written by export (dx, dy, 0).
std::vector<float> read_flow(const fs::path& p) {
    const Image f = read_image_file(p.string()).image;
    std::vector<float> out;
    for (int y = 0; y < f.height; ++y)
        for (int x = 0; x < f.width; ++x)
            out.push_back(f.at(x, y, 0)), out.push_back(f.at(x, y, 1));
    return out;
}

}  // namespace

TEST_CASE("uv_flow: the flow a known mapping implies, per layer, up to the frame's edge") {
    const int h = 36, w = 64;
    Layers a, b;
    a.uv_bg = affine_uv(h, w, 0, 0, 0.02);
    b.uv_bg = affine_uv(h, w, 1.5, -0.7, 0.02);  // the background moves by (1.5, -0.7)
    a.uv_fg = affine_uv(h, w, 0, 0, 0.0);
    b.uv_fg = affine_uv(h, w, -2.25, 3.0, 0.0);  // the subject by (-2.25, 3)
    a.alpha = torch::zeros({1, 1, h, w});
    a.alpha.index_put_({0, 0, torch::indexing::Slice(10, 20), torch::indexing::Slice(20, 40)}, 1.0);
    const Image f = uv_flow(a, b);
    double worst_bg = 0, worst_fg = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool fg = y >= 10 && y < 20 && x >= 20 && x < 40;
            const double ex = f.at(x, y, 0) - (fg ? -2.25 : 1.5);
            const double ey = f.at(x, y, 1) - (fg ? 3.0 : -0.7);
            (fg ? worst_fg : worst_bg) = std::max(fg ? worst_fg : worst_bg, std::hypot(ex, ey));
        }
    CHECK(worst_bg < 1e-3);  // the right column leaves the frame: still (1.5, -0.7)
    CHECK(worst_fg < 1e-3);
}

TEST_CASE("export --what flow: the fitted mappings' flow against a synth clip's true flow") {
    // The clip as `refocus synth --scene pan --size 160x90 --frames 8` writes it; its true flow
    // rendered here (the files' 2 channels are not a clip layout).
    SynthOptions so;
    so.scene = "pan", so.width = 160, so.height = 90, so.frames = 8;
    const fs::path root = scratch_dir("uv_flow");
    write_synth_clip(so, (root / "clip").string());
    const SynthClip synth(so);
    REQUIRE(cli("new '" + (root / "clip/input_%04d.png").string() + "' -o '" +
                (root / "p").string() + "'")
                .code == 0);
    REQUIRE(cli("fit '" + (root / "p").string() + "' --iters 60 --coc '" +
                (root / "clip/coc_%04d.exr").string() + "'")
                .code == 0);
    const auto r = cli("export '" + (root / "p").string() + "' --what flow --out '" +
                       (root / "flow").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    std::vector<double> epe;
    for (int t = 0; t + 1 < so.frames; ++t) {
        const auto got = read_flow(root / "flow" / ("flow_000" + std::to_string(t) + ".exr"));
        const Image want = synth.render(t).flow;
        REQUIRE(got.size() == want.pixels.size());
        for (size_t i = 0; i < got.size(); i += 2)
            epe.push_back(std::hypot(got[i] - want.pixels[i], got[i + 1] - want.pixels[i + 1]));
    }
    std::nth_element(epe.begin(), epe.begin() + epe.size() / 2, epe.end());
    MESSAGE("median end-point error " << epe[epe.size() / 2] << " px");
    CHECK(epe[epe.size() / 2] < 0.25);  // 0.06 px when written (the camera pans 3 px a frame)
    // The last frame has no next one: 0, as the synth clips write it.
    const auto last = read_flow(root / "flow/flow_0007.exr");
    CHECK(*std::max_element(last.begin(), last.end()) == 0.0f);
}
