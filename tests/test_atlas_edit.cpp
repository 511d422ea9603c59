// Atlas editing (paper Fig. 1): brush strokes, undo/redo, import/export of a repainted atlas,
// project files, and the edit following every rendered frame through the UV mapping (eq. 1).
#include <torch/torch.h>
#undef CHECK  // glog's (through torch): doctest's CHECK below

#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "edit/atlas_edit.h"
#include "io/tensor_image.h"
#include "io/clip.h"
#include "io/image_file.h"
#include "util/error.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

Image grey_base(int w = 32, int h = 32, float v = 0.5f) {
    return Image(w, h, 3, v);
}

AtlasEditor editor_on(const Image& base) {
    AtlasEditor e;
    e.set_base(base);
    return e;
}

Brush brush(float size, float hardness, float opacity, Brush::Mode mode = Brush::Paint) {
    Brush b;
    b.color[0] = 1.0f, b.color[1] = 0.0f, b.color[2] = 0.0f;
    b.size = size, b.hardness = hardness, b.opacity = opacity, b.mode = mode;
    return b;
}

float alpha(const AtlasEditor& e, int x, int y) {
    return e.edit().at(x, y, 3);
}

std::string error_of(const std::function<void()>& f) {
    try {
        f();
    } catch (const std::exception& e) {
        return e.what();
    }
    return "";
}

}  // namespace

TEST_CASE("dab coverage: hard edge, soft falloff, opacity") {
    CHECK(dab_coverage(0.0f, 10, 1) == 1.0f);
    CHECK(dab_coverage(4.4f, 10, 1) == 1.0f);
    CHECK(dab_coverage(5.0f, 10, 1) == doctest::Approx(0.5f));
    CHECK(dab_coverage(5.6f, 10, 1) == 0.0f);
    // Soft: falls monotonically from the centre.
    float prev = 2.0f;
    for (float d = 0; d < 6; d += 0.5f) {
        CHECK(dab_coverage(d, 10, 0) <= prev);
        prev = dab_coverage(d, 10, 0);
    }
    CHECK(dab_coverage(2.5f, 10, 0) == doctest::Approx(0.5f));
    CHECK(dab_coverage(2.5f, 10, 0.5f) == 1.0f);  // inside the hard core

    AtlasEditor e = editor_on(grey_base());
    CHECK_FALSE(e.has_edits());
    e.begin_stroke(brush(10, 1, 1));
    e.dab(16.5f, 16.5f);
    e.end_stroke();
    CHECK(e.has_edits());
    CHECK(alpha(e, 16, 16) == 1.0f);
    CHECK(alpha(e, 20, 16) == 1.0f);
    CHECK(alpha(e, 22, 16) == 0.0f);
    CHECK(e.result().at(16, 16, 0) == 1.0f);
    CHECK(e.result().at(16, 16, 1) == 0.0f);
    CHECK(e.result().at(2, 2, 1) == 0.5f);
}

TEST_CASE("opacity is the max within a stroke (no build-up) and builds across strokes") {
    AtlasEditor e = editor_on(grey_base());
    e.begin_stroke(brush(8, 1, 0.5f));
    e.dab(16.5f, 16.5f);
    e.stroke_to(17.5f, 16.5f);
    e.stroke_to(16.5f, 16.5f);
    e.dab(16.5f, 16.5f);
    e.end_stroke();
    CHECK(alpha(e, 16, 16) == doctest::Approx(0.5f));
    CHECK(e.result().at(16, 16, 0) == doctest::Approx(0.75f));  // 0.5 over grey 0.5
    e.begin_stroke(brush(8, 1, 0.5f));
    e.dab(16.5f, 16.5f);
    e.end_stroke();
    CHECK(alpha(e, 16, 16) == doctest::Approx(0.75f));

    // A long stroke covers its path with spaced dabs.
    AtlasEditor s = editor_on(grey_base());
    s.begin_stroke(brush(4, 1, 1));
    s.dab(4.5f, 10.5f);
    s.stroke_to(27.5f, 10.5f);
    s.end_stroke();
    for (int x = 4; x <= 27; ++x) CHECK(alpha(s, x, 10) == 1.0f);
    CHECK(alpha(s, 4, 20) == 0.0f);
}

TEST_CASE("erase shows the fitted atlas again; clone copies from the offset") {
    Image base(32, 32, 3);
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x)
            for (int c = 0; c < 3; ++c) base.at(x, y, c) = 0.01f * x + 0.02f * y + 0.1f * c;
    AtlasEditor e = editor_on(base);
    e.begin_stroke(brush(12, 1, 1));
    e.dab(16, 16);
    e.end_stroke();
    e.begin_stroke(brush(6, 1, 1, Brush::Erase));
    e.dab(16.5f, 16.5f);
    e.end_stroke();
    CHECK(alpha(e, 16, 16) == 0.0f);
    CHECK(e.result().at(16, 16, 1) == base.at(16, 16, 1));
    CHECK(alpha(e, 11, 16) == 1.0f);  // outside the eraser: still painted

    AtlasEditor c = editor_on(base);
    Brush cb = brush(5, 1, 1, Brush::Clone);
    cb.clone_dx = 8, cb.clone_dy = -3;
    c.begin_stroke(cb);
    c.dab(8.5f, 8.5f);
    c.end_stroke();
    for (int dx = -1; dx <= 1; ++dx)
        for (int k = 0; k < 3; ++k)
            CHECK(c.result().at(8 + dx, 8, k) ==
                  doctest::Approx(base.at(16 + dx, 5, k)).epsilon(1e-6));
    CHECK(c.result().at(20, 20, 0) == base.at(20, 20, 0));
}

TEST_CASE("undo/redo restore bit-exact; the history is capped") {
    AtlasEditor e = editor_on(grey_base(48, 40));
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(0.0f, 48.0f);
    std::vector<std::vector<float>> states{e.edit().pixels};
    for (int s = 0; s < 12; ++s) {
        Brush b = brush(3 + s, 0.1f * (s % 10), 0.3f + 0.05f * s,
                        s % 4 == 3 ? Brush::Erase : Brush::Paint);
        b.color[1] = 0.1f * s;
        e.begin_stroke(b);
        e.dab(u(rng), u(rng));
        e.stroke_to(u(rng), u(rng));
        e.end_stroke();
        states.push_back(e.edit().pixels);
    }
    for (int s = 12; s > 0; --s) {
        REQUIRE(e.can_undo());
        const int64_t v = e.version();
        e.undo();
        CHECK(e.version() > v);
        CHECK(e.edit().pixels == states[s - 1]);
    }
    CHECK_FALSE(e.can_undo());
    CHECK_FALSE(e.has_edits());
    for (int s = 1; s <= 12; ++s) {
        e.redo();
        CHECK(e.edit().pixels == states[s]);
    }
    CHECK_FALSE(e.can_redo());
    // A new stroke after an undo drops the redo branch.
    e.undo();
    e.begin_stroke(brush(5, 1, 1));
    e.dab(3, 3);
    e.end_stroke();
    CHECK_FALSE(e.can_redo());

    // Memory cap: a step stores its dirty rectangle only (a 6 px dab: 7x7 RGBA before and
    // after); with room for three, the oldest are dropped.
    AtlasEditor m = editor_on(grey_base());
    m.begin_stroke(brush(6, 1, 1));
    m.dab(4.5f, 16.5f);
    m.end_stroke();
    CHECK(m.undo_bytes() == 2 * 7 * 7 * 4 * sizeof(float));
    const size_t limit = 3 * m.undo_bytes() + 100;
    m.set_undo_limit(limit);
    for (int s = 1; s < 10; ++s) {
        m.begin_stroke(brush(6, 1, 1));
        m.dab(4.5f + 2 * s, 16.5f);
        m.end_stroke();
        CHECK(m.undo_bytes() <= limit);
    }
    int undos = 0;
    while (m.can_undo()) m.undo(), ++undos;
    CHECK(undos == 3);
    CHECK(m.has_edits());  // the oldest strokes can no longer be undone
}

TEST_CASE("eyedropper picks the result") {
    AtlasEditor e = editor_on(grey_base(16, 16, 0.25f));
    e.begin_stroke(brush(4, 1, 1));
    e.dab(4.5f, 4.5f);
    e.end_stroke();
    auto p = e.pick(4.9f, 4.1f);
    CHECK(p[0] == 1.0f);
    CHECK(p[1] == 0.0f);
    p = e.pick(12.0f, 12.0f);
    CHECK(p[0] == 0.25f);
    p = e.pick(-5.0f, 100.0f);  // clamped
    CHECK(p[2] == 0.25f);
}

TEST_CASE("import a repainted atlas: only changed pixels become the edit") {
    fs::path dir = scratch_dir("atlas_import");
    Image base(40, 24, 3);
    for (int y = 0; y < 24; ++y)
        for (int x = 0; x < 40; ++x)
            for (int c = 0; c < 3; ++c)
                base.at(x, y, c) = srgb_to_linear(0.1f + 0.02f * x + 0.01f * c);
    base.at(3, 3, 0) = 1.7f;  // an HDR texel: PNG clamps it, that is no edit
    AtlasEditor e = editor_on(base);
    const std::string same = (dir / "same.png").string();
    e.export_image(same, PixelFormat::Png8);
    const int64_t v = e.version();
    CHECK(e.import_image(same) == 0);
    CHECK_FALSE(e.has_edits());
    CHECK_FALSE(e.can_undo());

    Image painted = read_image_file(same).image;
    for (int y = 5; y < 10; ++y)
        for (int x = 20; x < 30; ++x)
            painted.at(x, y, 0) = 1.0f, painted.at(x, y, 1) = painted.at(x, y, 2) = 0.0f;
    const std::string red = (dir / "red.tif").string();
    write_image_file(red, painted, PixelFormat::Tiff16);
    CHECK(e.import_image(red) == 50);
    CHECK(e.version() > v);
    for (int y = 0; y < 24; ++y)
        for (int x = 0; x < 40; ++x) {
            const bool in = x >= 20 && x < 30 && y >= 5 && y < 10;
            REQUIRE(alpha(e, x, y) == (in ? 1.0f : 0.0f));
        }
    CHECK(e.result().at(3, 3, 0) == 1.7f);
    CHECK(e.result().at(25, 7, 0) == doctest::Approx(1.0f));
    e.undo();  // one step
    CHECK_FALSE(e.has_edits());
    e.redo();
    CHECK(e.has_edits());

    const std::string small = (dir / "small.png").string();
    write_image_file(small, Image(16, 8, 3, 0.5f), PixelFormat::Png8);
    std::string err = error_of([&] { e.import_image(small); });
    CHECK(err.find("small.png") != std::string::npos);
    CHECK(err.find("16x8") != std::string::npos);
    CHECK(err.find("40x24") != std::string::npos);
    err = error_of([&] { e.import_image((dir / "nope.png").string()); });
    CHECK(err.find("nope.png") != std::string::npos);
    CHECK(e.has_edits());  // failures leave the edit as it was

    Image nan = base;
    nan.at(1, 1, 1) = NAN;
    write_image_file((dir / "nan.exr").string(), nan, PixelFormat::ExrFloat);
    CHECK(error_of([&] { e.import_image((dir / "nan.exr").string()); }).find("nan.exr") !=
          std::string::npos);
}

TEST_CASE("export round trip: PNG 8, TIFF 16, EXR") {
    fs::path dir = scratch_dir("atlas_export");
    Image base(20, 12, 3);
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (float& p : base.pixels) p = u(rng);
    AtlasEditor e = editor_on(base);
    e.begin_stroke(brush(6, 0.3f, 0.7f));
    e.dab(10, 6);
    e.end_stroke();
    const Image want = e.result();
    struct Case {
        PixelFormat f;
        const char* name;
        double tol;
    };
    for (Case c :
         {Case{PixelFormat::Png8, "a.png", 0.51 / 255}, Case{PixelFormat::Tiff16, "a.tif", 1e-4},
          Case{PixelFormat::ExrHalf, "a.exr", 1e-3}, Case{PixelFormat::ExrFloat, "b.exr", 0}}) {
        const std::string path = (dir / c.name).string();
        e.export_image(path, c.f);
        Image got = read_image_file(path).image;
        REQUIRE(got.same_shape(want));
        double worst = 0;
        for (size_t i = 0; i < got.size(); ++i)
            worst = std::max(worst, double(std::abs(linear_to_srgb(got.pixels[i]) -
                                                    linear_to_srgb(want.pixels[i]))));
        CHECK_MESSAGE(worst <= c.tol + 1e-6, c.name << ": " << worst);
        // Importing one's own export is no edit beyond the painted one.
        AtlasEditor again = editor_on(base);
        again.import_image(path);
        for (int y = 0; y < 12; ++y)
            for (int x = 0; x < 20; ++x)
                if (alpha(e, x, y) == 0.0f) REQUIRE(alpha(again, x, y) == 0.0f);
    }
}

TEST_CASE("project edits: save/load round trip, size check names the file, no files = no edits") {
    fs::path dir = scratch_dir("atlas_project");
    write_png_sequence(dir / "clip", {pattern_frame(16, 16, 0), pattern_frame(16, 16, 1)});
    Project p = create_project((dir / "clip").string(), dir / "proj", {});
    ProjectEdits none = ProjectEdits::load(p);
    CHECK_FALSE(none.has_edits());

    ProjectEdits ed;
    ed.bg.set_base(grey_base(24, 20));
    ed.bg.begin_stroke(brush(5, 0.5f, 0.8f));
    ed.bg.dab(7, 9);
    ed.bg.end_stroke();
    ed.fg.set_base(grey_base(10, 10));
    ed.save(p);
    CHECK(fs::exists(dir / "proj" / "edits" / "edit_bg.exr"));
    CHECK_FALSE(fs::exists(dir / "proj" / "edits" / "edit_fg.exr"));
    Project reloaded = Project::load(dir / "proj");
    REQUIRE(reloaded.sections.contains("edits"));
    CHECK(reloaded.sections["edits"]["bg"] == "edits/edit_bg.exr");
    ProjectEdits back = ProjectEdits::load(reloaded);
    CHECK(back.bg.edit().pixels == ed.bg.edit().pixels);
    CHECK_FALSE(back.fg.has_edits());
    back.bg.set_base(grey_base(24, 20, 0.1f));  // training moved on: the edit is kept
    CHECK(back.bg.edit().pixels == ed.bg.edit().pixels);
    std::string err =
        error_of([&] { ProjectEdits::load(reloaded).bg.set_base(grey_base(30, 20)); });
    CHECK(err.find("edit_bg.exr") != std::string::npos);
    CHECK(err.find("24x20") != std::string::npos);
    CHECK(err.find("30x20") != std::string::npos);

    // A refit at twice (or half) the atlas resolution carries the edit over, resampled: the
    // dab's centre stays at the same atlas coordinate, its opacity and colour with it.
    {
        ProjectEdits two = ProjectEdits::load(reloaded);
        two.bg.set_base(grey_base(48, 40));
        const Image& e2 = two.bg.edit();
        REQUIRE(e2.width == 48);
        REQUIRE(e2.height == 40);
        const Image& e1 = ed.bg.edit();
        // 1x texel (7, 9) covers 2x texels 14..15 x 18..19.
        CHECK(e2.at(14, 18, 3) == doctest::Approx(e1.at(7, 9, 3)).epsilon(0.05));
        CHECK(e2.at(15, 19, 0) == doctest::Approx(e1.at(7, 9, 0)).epsilon(0.01));
        double s1 = 0, s2 = 0;  // the edit's coverage, in 1x texels
        for (int y = 0; y < 20; ++y)
            for (int x = 0; x < 24; ++x) s1 += e1.at(x, y, 3);
        for (int y = 0; y < 40; ++y)
            for (int x = 0; x < 48; ++x) s2 += e2.at(x, y, 3) / 4;
        CHECK(s2 == doctest::Approx(s1).epsilon(0.02));
        two.bg.set_base(grey_base(24, 20));  // and back down
        CHECK(two.bg.edit().at(7, 9, 3) == doctest::Approx(e1.at(7, 9, 3)).epsilon(0.05));
    }

    // Clearing removes the file and the listing.
    back.bg.clear();
    back.save(reloaded);
    CHECK_FALSE(fs::exists(dir / "proj" / "edits" / "edit_bg.exr"));
    CHECK_FALSE(ProjectEdits::load(Project::load(dir / "proj")).has_edits());
}

TEST_CASE("apply_edits: exact no-op without edits; the edit lands where the UV maps it") {
    torch::manual_seed(1);
    const int64_t H = 12, W = 16;
    Layers L;
    L.bg = torch::rand({2, 3, H, W});
    L.sharp = L.bg;
    L.uv_bg = torch::rand({2, H, W, 2}) * 2 - 1;
    Layers before = L;
    apply_edits(L, {}, {});
    CHECK(L.sharp.is_same(before.sharp));
    CHECK(L.bg.is_same(before.bg));

    // Identity mapping: frame pixel (x, y) ↔ atlas pixel (x, y) (align_corners = false).
    auto ys = torch::arange(H, torch::kFloat32), xs = torch::arange(W, torch::kFloat32);
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto uv =
        torch::stack({(g[1] + 0.5) * (2.0 / W) - 1, (g[0] + 0.5) * (2.0 / H) - 1}, -1).unsqueeze(0);
    Image base_img(int(W), int(H), 3);
    for (size_t i = 0; i < base_img.size(); ++i) base_img.pixels[i] = 0.01f * (i % 77);
    auto base = image_to_tensor(base_img);
    AtlasEditor e = editor_on(base_img);
    CHECK_FALSE(e.delta(base).defined());
    e.begin_stroke(brush(4, 1, 1));
    e.dab(5.0f, 6.0f);  // covers pixels 3..6 × 4..7
    e.end_stroke();
    auto d = e.delta(base);
    REQUIRE(d.defined());

    Layers one;
    one.bg = base.unsqueeze(0);
    one.sharp = one.bg;
    one.uv_bg = uv;
    apply_edits(one, d, {});
    auto want = image_to_tensor(e.result()).unsqueeze(0);
    CHECK((one.sharp - want).abs().max().item<float>() < 1e-5f);
    CHECK(one.sharp[0][0][5][4].item<float>() == doctest::Approx(1.0f));
    CHECK(one.sharp[0][1][0][0].item<float>() == base[1][0][0].item<float>());

    // Two layers: sharp = α·fg + (1−α)·(bg + edit)  (paper eq. 1).
    Layers two;
    two.bg = base.unsqueeze(0);
    two.fg = torch::full({1, 3, H, W}, 0.2f);
    two.alpha = torch::full({1, 1, H, W}, 0.25f);
    two.uv_bg = uv;
    two.uv_fg = uv;
    two.sharp = two.alpha * two.fg + (1 - two.alpha) * two.bg;
    apply_edits(two, d, {});
    CHECK((two.sharp - (0.25f * 0.2f + 0.75f * want)).abs().max().item<float>() < 1e-5f);
}

TEST_CASE("CLI: refocus atlas --import a red square; refocus export shows it in every frame") {
    fs::path dir = scratch_dir("atlas_cli");
    RunResult r = cli("synth --scene tripod -o '" + (dir / "clip").string() +
                      "' --size 48x32 --frames 4 --seed 2");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    const std::string proj = (dir / "proj").string();
    r = cli("new '" + (dir / "clip" / "input_%04d.png").string() + "' -o '" + proj + "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    r = cli("fit '" + proj + "' --iters 3 --coc '" + (dir / "clip" / "coc_%04d.exr").string() +
            "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    r = cli("export '" + proj + "' --what atlas --format png --out '" + (dir / "atlas").string() +
            "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);

    auto red_pixels = [](const Image& f) {
        int n = 0;
        for (int y = 0; y < f.height; ++y)
            for (int x = 0; x < f.width; ++x)
                n += f.at(x, y, 0) > 0.9f && f.at(x, y, 1) < 0.05f && f.at(x, y, 2) < 0.05f;
        return n;
    };
    Image atlas = read_image_file((dir / "atlas" / "atlas_bg.png").string()).image;
    CHECK(red_pixels(atlas) == 0);
    for (int y = atlas.height / 4; y < atlas.height * 3 / 4; ++y)
        for (int x = atlas.width / 4; x < atlas.width * 3 / 4; ++x)
            atlas.at(x, y, 0) = 1.0f, atlas.at(x, y, 1) = atlas.at(x, y, 2) = 0.0f;
    write_image_file((dir / "red.png").string(), atlas, PixelFormat::Png8);

    r = cli("atlas '" + proj + "' --import '" + (dir / "red.png").string() + "' --layer bg");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    CHECK(fs::exists(dir / "proj" / "edits" / "edit_bg.exr"));
    r = cli("export '" + proj + "' --what sharp --format png --out '" + (dir / "sharp").string() +
            "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    auto frames = read_all_frames((dir / "sharp" / "sharp_%04d.png").string());
    REQUIRE(frames.size() == 4);
    for (const Image& f : frames) CHECK(red_pixels(f) > f.width * f.height / 8);
    r = cli("export '" + proj + "' --what atlas --format png --out '" + (dir / "atlas2").string() +
            "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    CHECK(red_pixels(read_image_file((dir / "atlas2" / "atlas_bg.png").string()).image) ==
          (atlas.width / 2) * (atlas.height / 2));

    r = cli("atlas '" + proj + "' --import '" + (dir / "red.png").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("--layer") != std::string::npos);
    r = cli("atlas '" + proj + "' --clear");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    r = cli("export '" + proj + "' --what sharp --format png --out '" + (dir / "sharp2").string() +
            "'");
    REQUIRE_MESSAGE(r.code == 0, r.output);
    for (const Image& f : read_all_frames((dir / "sharp2" / "sharp_%04d.png").string()))
        CHECK(red_pixels(f) == 0);
}
