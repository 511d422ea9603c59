// Clip input/output: round trips for every format and every bad-input case.
#include <doctest/doctest.h>

#include <Imath/half.h>
#include <OpenImageIO/imageio.h>

#include <cmath>
#include <fstream>
#include <limits>

#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "test_util.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// Snaps linear values to what an encoding can hold exactly, so lossless round trips are
// bit-exact comparisons.
Image quantize_srgb(const Image& img, int levels) {
    Image q = img;
    for (float& v : q.pixels) {
        long code = std::lround(linear_to_srgb(v) * levels);
        v = levels == 255 ? srgb8_to_linear_table()[code] : srgb_to_linear(float(code) / levels);
    }
    return q;
}

Image quantize_half(const Image& img) {
    Image q = img;
    for (float& v : q.pixels) v = float(Imath::half(v));
    return q;
}

bool same_codes16(const Image& a, const Image& b) {
    for (size_t i = 0; i < a.size(); ++i)
        if (linear_to_srgb16(a.pixels[i]) != linear_to_srgb16(b.pixels[i])) return false;
    return a.same_shape(b);
}

std::vector<Image> make_frames(int n, int w = 64, int h = 36) {
    std::vector<Image> f;
    for (int i = 0; i < n; ++i) f.push_back(pattern_frame(w, h, i));
    return f;
}

void write_raw_oiio(const std::string& path, int w, int h, int nch, const std::vector<float>& px) {
    auto out = OIIO::ImageOutput::create(path);
    REQUIRE(out);
    OIIO::ImageSpec spec(
        w, h, nch,
        path.find(".exr") != std::string::npos ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8);
    REQUIRE(out->open(path, spec));
    REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
}

// Runs `refocus info` on `what` and checks it fails with a one-line message naming `names`.
void expect_cli_error(const std::string& what, const std::string& names,
                      const std::string& problem) {
    RunResult r = cli("info '" + what + "'");
    INFO(r.output);
    CHECK(r.code != 0);
    CHECK(r.output.find(names) != std::string::npos);
    CHECK(r.output.find(problem) != std::string::npos);
    CHECK(r.output.find("error:") != std::string::npos);
}

}  // namespace

TEST_CASE("lossless sequence round trips are bit-exact") {
    fs::path dir = scratch_dir("io_roundtrip");
    std::vector<Image> frames = make_frames(3);
    struct Case {
        const char* format;
        int srgb_levels;  // 0: float storage
        bool half;
    } cases[] = {{"png", 255, false},
                 {"png16", 65535, false},
                 {"tiff", 65535, false},
                 {"exr", 0, true},
                 {"exr32", 0, false}};
    for (const auto& c : cases) {
        CAPTURE(c.format);
        std::vector<Image> expect;
        for (const auto& f : frames)
            expect.push_back(c.srgb_levels ? quantize_srgb(f, c.srgb_levels)
                                           : (c.half ? quantize_half(f) : f));
        fs::path out = dir / c.format;
        ClipWriter w(out.string(), "plate", parse_clip_format(c.format));
        for (const auto& f : expect) w.write(f);
        auto files = w.finish();
        REQUIRE(files.size() == 3);
        // <name>_%04d.<ext>, counting from 0.
        CHECK(fs::path(files[0]).filename().string().rfind("plate_0000.", 0) == 0);
        CHECK(fs::path(files[2]).filename().string().rfind("plate_0002.", 0) == 0);
        ClipInfo info;
        auto back = read_all_frames(out.string(), {}, &info);
        REQUIRE(back.size() == 3);
        CHECK(info.width == 64);
        CHECK(info.height == 36);
        CHECK(info.source_linear == (c.srgb_levels == 0));
        for (size_t i = 0; i < back.size(); ++i) {
            if (c.srgb_levels == 65535) {
                // 16-bit: the stored code values must match exactly (decode rounding may differ
                // in the last float bit between our quantiser and the reader).
                CHECK(same_codes16(back[i], expect[i]));
                CHECK(max_abs_diff(back[i], expect[i]) < 1e-6);
            } else {
                CHECK(max_abs_diff(back[i], expect[i]) == 0.0);
            }
        }
    }
}

TEST_CASE("mp4 round trip within codec error, and agrees with the PNG sequence") {
    fs::path dir = scratch_dir("io_mp4");
    // The test frames hold per-pixel noise and a 4 px blue/yellow checkerboard: chroma detail
    // that 4:2:0 subsampling removes by design. Stated bound: every frame above 30 dB (measured
    // 32.2 dB at CRF 14); flat colours come back within 2 code levels (see the next test).
    std::vector<Image> frames = make_frames(10, 96, 64);
    ClipWriteOptions opts;
    opts.fps = 25;
    {
        ClipWriter w((dir / "clip.mp4").string(), "clip", ClipFormat::Mp4, opts);
        for (const auto& f : frames) w.write(f);
        auto files = w.finish();
        REQUIRE(files.size() == 1);
    }
    write_png_sequence(dir / "png", frames);
    ClipInfo vinfo, sinfo;
    auto video = read_all_frames((dir / "clip.mp4").string(), {}, &vinfo);
    auto seq = read_all_frames((dir / "png").string(), {}, &sinfo);
    REQUIRE(video.size() == 10);
    REQUIRE(seq.size() == 10);
    CHECK(vinfo.fps == doctest::Approx(25.0));
    CHECK(vinfo.kind == "video");
    CHECK(sinfo.kind == "sequence");
    double worst = 1e9;
    for (int i = 0; i < 10; ++i) worst = std::min(worst, psnr(video[i], seq[i]));
    MESSAGE("mp4 vs PNG worst-frame PSNR: " << worst << " dB");
    CHECK(worst > 30.0);
    // Mean colour must not shift (matrix/range mismatch would move it by several levels).
    double ms = 0, mv = 0;
    for (size_t i = 0; i < video[3].size(); ++i) {
        ms += linear_to_srgb(seq[3].pixels[i]);
        mv += linear_to_srgb(video[3].pixels[i]);
    }
    CHECK(std::abs(ms - mv) / video[3].size() < 2.0 / 255);
}

TEST_CASE("mp4 keeps flat colours within 2 code levels (BT.601 matrix on both sides)") {
    fs::path dir = scratch_dir("io_mp4_flat");
    const float cols[4][3] = {
        {0.5f, 0.2f, 0.1f}, {0.05f, 0.6f, 0.3f}, {0.9f, 0.9f, 0.9f}, {0.01f, 0.02f, 0.5f}};
    {
        ClipWriter w((dir / "flat.mp4").string(), "flat", ClipFormat::Mp4);
        for (const auto& c : cols) {
            Image im(64, 64, 3);
            for (size_t i = 0; i < im.size(); ++i) im.pixels[i] = c[i % 3];
            w.write(im);
        }
        w.finish();
    }
    auto back = read_all_frames((dir / "flat.mp4").string());
    REQUIRE(back.size() == 4);
    for (int k = 0; k < 4; ++k)
        for (int c = 0; c < 3; ++c) {
            CAPTURE(k);
            CAPTURE(c);
            CHECK(std::abs(int(linear_to_srgb8(back[k].at(32, 32, c))) -
                           int(linear_to_srgb8(cols[k][c]))) <= 2);
        }
}

TEST_CASE("odd-sized frames survive an mp4 round trip at their size") {
    fs::path dir = scratch_dir("io_mp4_odd");
    auto frames = make_frames(3, 33, 21);
    ClipWriter w((dir / "odd.mp4").string(), "odd", ClipFormat::Mp4);
    for (const auto& f : frames) w.write(f);
    w.finish();
    ClipInfo info;
    auto back = read_all_frames((dir / "odd.mp4").string(), {}, &info);
    CHECK(info.width == 33);
    CHECK(info.height == 21);
    CHECK(back.size() == 3);
}

TEST_CASE("a writer that is not finished leaves nothing behind") {
    fs::path dir = scratch_dir("io_cancel");
    {
        ClipWriter w((dir / "seq").string(), "x", ClipFormat::Png8);
        w.write(pattern_frame(16, 16, 0));
        w.write(pattern_frame(16, 16, 1));
    }
    CHECK(fs::is_empty(dir / "seq"));
    {
        ClipWriter w((dir / "v.mp4").string(), "v", ClipFormat::Mp4);
        w.write(pattern_frame(16, 16, 0));
    }
    CHECK(!fs::exists(dir / "v.mp4"));
    size_t n = std::distance(fs::directory_iterator(dir), fs::directory_iterator());
    CHECK(n == 1);  // only "seq": no temporary files left
}

TEST_CASE("printf patterns, folders, 16-bit and grey/RGBA inputs") {
    fs::path dir = scratch_dir("io_patterns");
    auto frames = make_frames(4, 32, 20);
    write_png_sequence(dir / "a", frames, true);
    ClipInfo info;
    auto back = read_all_frames((dir / "a" / "frame_%04d.png").string(), {}, &info);
    CHECK(back.size() == 4);
    CHECK(info.source_format == "uint16");
    CHECK(same_codes16(back[2], quantize_srgb(frames[2], 65535)));
    // Grey and RGBA: grey is replicated, alpha dropped.
    std::vector<float> grey(32 * 20, 0.5f), rgba(32 * 20 * 4, 1.0f);
    fs::create_directories(dir / "g");
    write_raw_oiio((dir / "g" / "g_0000.exr").string(), 32, 20, 1, grey);
    auto g = read_all_frames((dir / "g").string());
    REQUIRE(g.size() == 1);
    CHECK(g[0].channels == 3);
    CHECK(g[0].at(5, 5, 2) == 0.5f);
    fs::create_directories(dir / "rgba");
    write_raw_oiio((dir / "rgba" / "f_0000.png").string(), 32, 20, 4, rgba);
    auto r = read_all_frames((dir / "rgba").string());
    CHECK(r[0].channels == 3);
    CHECK(r[0].at(1, 1, 0) == doctest::Approx(1.0f));
}

TEST_CASE("bad input: one line naming the file and the problem, non-zero exit") {
    fs::path dir = scratch_dir("io_bad");

    SUBCASE("missing file") {
        expect_cli_error((dir / "nope.mp4").string(), "nope.mp4", "no such file");
    }

    SUBCASE("empty video file") {
        std::ofstream((dir / "empty.mp4").string()).close();
        expect_cli_error((dir / "empty.mp4").string(), "empty.mp4", "zero frames");
    }

    SUBCASE("truncated video") {
        auto frames = make_frames(12, 64, 36);
        {
            ClipWriter w((dir / "full.mp4").string(), "f", ClipFormat::Mp4);
            for (const auto& f : frames) w.write(f);
            w.finish();
        }
        // Keep the header (faststart puts it first) and cut the frame data in half.
        std::ifstream in((dir / "full.mp4").string(), std::ios::binary);
        std::string bytes((std::istreambuf_iterator<char>(in)), {});
        std::ofstream((dir / "cut.mp4").string(), std::ios::binary)
            .write(bytes.data(), static_cast<long>(bytes.size() / 2));
        RunResult r = cli("info '" + (dir / "cut.mp4").string() + "'");
        INFO(r.output);
        CHECK(r.code != 0);
        CHECK(r.output.find("cut.mp4") != std::string::npos);
        // A header-less file is "corrupt"; a cut one with its header is "truncated".
        CHECK((r.output.find("truncated") != std::string::npos ||
               r.output.find("corrupt") != std::string::npos));
    }

    SUBCASE("truncated PNG in a sequence") {
        auto frames = make_frames(3, 64, 36);
        write_png_sequence(dir / "seq", frames);
        fs::path f1 = dir / "seq" / "frame_0001.png";
        fs::resize_file(f1, fs::file_size(f1) / 2);
        auto reader = ClipReader::open((dir / "seq").string());
        reader->read(0);
        try {
            reader->read(1);
            FAIL("truncated frame was read");
        } catch (const Error& e) {
            std::string m = e.what();
            CHECK(m.find("frame_0001.png") != std::string::npos);
            CHECK(m.find("frame 1") != std::string::npos);
        }
    }

    SUBCASE("zero frames: empty folder and pattern with no match") {
        fs::create_directories(dir / "none");
        expect_cli_error((dir / "none").string(), "none", "zero frames");
        expect_cli_error((dir / "none" / "f_%04d.png").string(), "f_%04d.png", "zero frames");
    }

    SUBCASE("frames of different sizes") {
        write_png_sequence(dir / "mixed", {pattern_frame(32, 20, 0), pattern_frame(32, 20, 1)});
        write_image_file((dir / "mixed" / "frame_0002.png").string(), pattern_frame(30, 20, 2),
                         PixelFormat::Png8);
        expect_cli_error((dir / "mixed").string(), "frame_0002.png",
                         "differs from the first frame");
    }

    SUBCASE("gap in a numbered sequence") {
        write_png_sequence(dir / "gap", make_frames(4, 16, 16));
        fs::remove(dir / "gap" / "frame_0002.png");
        expect_cli_error((dir / "gap" / "frame_%04d.png").string(), "frame_%04d.png", "missing");
    }

    SUBCASE("unsupported channel count") {
        fs::create_directories(dir / "two");
        write_raw_oiio((dir / "two" / "f_0000.png").string(), 8, 8, 2,
                       std::vector<float>(128, 0.5f));
        expect_cli_error((dir / "two").string(), "f_0000.png", "unsupported channel count 2");
    }

    SUBCASE("NaN/Inf in EXR: rejected by default, cleaned on request") {
        fs::create_directories(dir / "nan");
        // 16x16: a project takes no clip under 12x12.
        std::vector<float> px(16 * 16 * 3, 0.25f);
        px[3 * (2 * 16 + 5) + 1] = std::numeric_limits<float>::quiet_NaN();  // pixel (5,2)
        px[10] = std::numeric_limits<float>::infinity();
        write_raw_oiio((dir / "nan" / "f_0000.exr").string(), 16, 16, 3, px);
        RunResult r =
            cli("new '" + (dir / "nan").string() + "' -o '" + (dir / "p1").string() + "'");
        INFO(r.output);
        CHECK(r.code != 0);
        CHECK(r.output.find("f_0000.exr") != std::string::npos);
        CHECK(r.output.find("2 NaN/Inf") != std::string::npos);
        CHECK(r.output.find("rejected") != std::string::npos);
        ClipReadOptions clean;
        clean.nonfinite = NonFinitePolicy::Clean;
        auto f = read_all_frames((dir / "nan").string(), clean);
        CHECK(count_nonfinite(f[0]) == 0);
        CHECK(f[0].at(5, 2, 1) == 0.0f);  // NaN → 0
        CHECK(f[0].pixels[10] == 0.25f);  // +Inf → largest finite value
    }

    SUBCASE("a file that is not an image") {
        fs::create_directories(dir / "junk");
        std::ofstream((dir / "junk" / "f_0000.png").string()) << "not a png at all";
        expect_cli_error((dir / "junk").string(), "f_0000.png", "cannot open image");
    }
}

TEST_CASE("frame patterns: one %d or %0Nd, everything else literal") {
    CHECK(format_pattern("frame_%04d.exr", 7) == "frame_0007.exr");
    CHECK(format_pattern("f%d.png", 12345) == "f12345.png");
    CHECK(format_pattern("100%%_%03d.png", 5) == "100%_005.png");
    CHECK(format_pattern("a_%010d", 3) == "a_0000000003");
    for (const char* bad : {"f_%n.exr", "%hhn", "%s%s%s%s", "f_%99999d.exr", "f_%011d.png",
                            "f_%d_%d.png", "frame.png", "f_%5d.png", "f_%", "f_%x.png"}) {
        INFO(bad);
        CHECK_THROWS_AS(format_pattern(bad, 1), Error);
        CHECK(!frame_pattern_problem(bad).empty());
    }
    try {
        parse_frame_pattern("f_%n.exr", "project.json");
        FAIL("accepted");
    } catch (const Error& e) {
        CHECK(std::string(e.what()).rfind("project.json: bad frame pattern 'f_%n.exr'", 0) == 0);
    }
}

TEST_CASE("an mp4 writer spawns ffmpeg without a shell and checks its output") {
    fs::path dir = scratch_dir("io_mp4_checked");
    const std::string name = (dir / "a 'b' $(touch X) ;c.mp4").string();
    ClipWriter w(name, "v", ClipFormat::Mp4);
    for (int i = 0; i < 3; ++i) w.write(pattern_frame(32, 16, i));
    auto files = w.finish();
    REQUIRE(files.size() == 1);
    CHECK(files[0] == name);
    CHECK(mp4_has_moov(name));
    CHECK(!fs::exists(dir / "X"));
    CHECK(!fs::exists("X"));
    std::ofstream((dir / "junk.mp4").string()) << "mdat and no header";
    CHECK(!mp4_has_moov((dir / "junk.mp4").string()));
}
