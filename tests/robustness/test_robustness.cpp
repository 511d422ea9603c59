// Hostile input and faults, through the CLI on tiny generated clips: no shell, no format strings
// from files, bounded JSON, validated budgets, checked writes, one writer per project, no silent
// wrong results; and a seeded fuzzer of project.json and checkpoint.json.
#include <OpenImageIO/imageio.h>
#include <doctest/doctest.h>
#include <sys/mount.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include "io/clip.h"
#include "io/image_file.h"
#include "project/project.h"
#include "robustness/robust_util.h"
#include "test_util.h"
#include "util/error.h"
#include "util/lock.h"

using namespace refocus;
using namespace refocus::test;
using nlohmann::json;

using namespace refocus::robust;

TEST_CASE("mp4 export: no shell, the injection path is a file name") {
    const Clip& c = fitted();
    const fs::path work = scratch_dir("robust_inject");
    fs::create_directories(work / "out");
    const std::string evil = "out/x';touch INJECTED;'.mp4";
    RunResult r = run("cd " + q(work.string()) + " && timeout 120 " + REFOCUS_CLI + " export " +
                      q(c.project.string()) + " --what sharp --format mp4 --out " + q(evil));
    INFO(r.output);
    CHECK(r.code == 0);
    CHECK(!fs::exists(work / "INJECTED"));
    CHECK(!fs::exists(work / "out" / "INJECTED"));
    REQUIRE(fs::exists(work / evil));
    CHECK(mp4_has_moov((work / evil).string()));
    auto reader = ClipReader::open((work / evil).string());
    CHECK(reader->info().frames == 6);
    size_t n = std::distance(fs::directory_iterator(work / "out"), fs::directory_iterator());
    CHECK(n == 1);  // the mp4 and no temporary

    // A path far past the old 1024-byte command line.
    fs::path deep = work / std::string(200, 'a') / std::string(200, 'b') / std::string(200, 'c');
    fs::create_directories(deep);
    r = cli_t("export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
              q((deep / "v -y $(touch X).mp4").string()));
    INFO(r.output);
    CHECK(r.code == 0);
    CHECK(fs::exists(deep / "v -y $(touch X).mp4"));
    CHECK(!fs::exists("X"));
}

TEST_CASE("mp4 export: an encoder that fails or leaves no moov keeps the previous file") {
    const Clip& c = fitted();
    const fs::path work = scratch_dir("robust_ffmpeg");
    const fs::path good = work / "good.mp4";
    RunResult r = cli_t("export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
                        q(good.string()));
    REQUIRE(r.code == 0);
    const std::string before = file_bytes(good);
    // Fake encoders: ffmpeg 5 exits 0 after "Error writing trailer"; one writes nothing.
    fs::create_directories(work / "bin1");
    fs::create_directories(work / "bin2");
    std::ofstream(work / "bin1" / "ffmpeg")
        << "#!/bin/sh\ncat >/dev/null\nfor a; do out=$a; done\nprintf 'mdat' > \"${out#file:}\"\n"
           "echo \"Error writing trailer of ${out}: No space left on device\" >&2\nexit 0\n";
    std::ofstream(work / "bin2" / "ffmpeg") << "#!/bin/sh\ncat >/dev/null\nexit 0\n";
    fs::permissions(work / "bin1" / "ffmpeg", fs::perms::owner_all);
    fs::permissions(work / "bin2" / "ffmpeg", fs::perms::owner_all);
    for (const char* bin : {"bin1", "bin2"}) {
        r = run("PATH=" + q((work / bin).string()) + ":$PATH timeout 120 " + REFOCUS_CLI +
                " export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
                q(good.string()));
        expect_clean_error(r, "good.mp4");
        CHECK(file_bytes(good) == before);
        CHECK(stray_temporaries(work).empty());
    }
    CHECK(r.output.find("wrote nothing") != std::string::npos);
    // No ffmpeg at all.
    r = run("timeout 120 env PATH=/nonexistent " + std::string(REFOCUS_CLI) + " export " +
            q(c.project.string()) + " --what sharp --format mp4 --out " + q(good.string()));
    expect_clean_error(r, "good.mp4", "ffmpeg");
    CHECK(file_bytes(good) == before);
}

TEST_CASE("sequence export over a good one: complete or untouched, never a mix") {
    const Clip& c = fitted();
    const fs::path out = scratch_dir("robust_seq") / "out";
    RunResult r = cli_t("export " + q(c.project.string()) + " --what sharp --format png --out " +
                        q(out.string()));
    REQUIRE(r.code == 0);
    // A longer, older export's extra frames are removed by a shorter one.
    std::ofstream(out / "sharp_0009.png") << "old";
    r = cli_t("export " + q(c.project.string()) + " --what sharp --format png --last 2 --out " +
              q(out.string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(!fs::exists(out / "sharp_0009.png"));
    CHECK(!fs::exists(out / "sharp_0003.png"));
    CHECK(fs::exists(out / "sharp_0002.png"));
    CHECK(stray_temporaries(out).empty());
}

TEST_CASE("full disk: failed writes exit non-zero and keep the old outputs") {
    const Clip& c = fitted();
    SmallDisk disk(scratch_dir("robust_full") / "disk", 400);
    if (!disk.ok) return;
    const fs::path out = disk.dir / "png";
    RunResult r = cli_t("export " + q(c.project.string()) + " --what sharp --format png16 --out " +
                        q(out.string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    std::map<std::string, std::string> before;
    for (const auto& e : fs::directory_iterator(out))
        before[e.path().string()] = file_bytes(e.path());
    const fs::path mp4 = disk.dir / "v.mp4";
    r = cli_t("export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
              q(mp4.string()));
    REQUIRE(r.code == 0);
    const std::string mp4_before = file_bytes(mp4);
    disk.fill(512);

    r = cli_t("export " + q(c.project.string()) + " --what sharp --format png16 --out " +
              q(out.string()));
    expect_clean_error(r, "sharp_", "No space left on device");
    for (const auto& [path, bytes] : before) CHECK(file_bytes(path) == bytes);
    CHECK(stray_temporaries(disk.dir).empty());

    r = cli_t("export " + q(c.project.string()) + " --what sharp --format exr32 --out " +
              q((disk.dir / "new").string()));
    expect_clean_error(r, "sharp_", "No space left on device");
    CHECK((!fs::exists(disk.dir / "new") || fs::is_empty(disk.dir / "new")));

    r = cli_t("export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
              q(mp4.string()));
    expect_clean_error(r, "v.mp4");
    CHECK(file_bytes(mp4) == mp4_before);

    r = cli_t("new " + q((c.clip / "input_%04d.png").string()) + " -o " +
              q((disk.dir / "p").string()));
    expect_clean_error(r, "No space left on device");
    CHECK(!fs::exists(disk.dir / "p"));
    r = cli_t("synth --quiet --scene tripod -o " + q((disk.dir / "s").string()) +
              " --size 64x64 --frames 6");
    expect_clean_error(r, "No space left on device");
    CHECK(!fs::exists(disk.dir / "s"));
    CHECK(stray_temporaries(disk.dir).empty());
}

TEST_CASE("frame patterns are parsed, never given to printf") {
    const Clip c = make_clip("robust_pattern");
    const std::string base = file_bytes(c.project / "project.json");
    for (const char* bad : {"frames/frame_%n.exr", "frames/frame_%hhn.exr", "frames/%s%s%s%s.exr",
                            "frames/frame_%99999d.exr", "frames/frame_%d_%d.exr",
                            "frames/frame.exr", "prep/coc_%04d.exr", "frames/frame_%x.exr"}) {
        json j = json::parse(base);
        j["cache"]["frames"] = bad;
        std::ofstream(c.project / "project.json") << j.dump(2);
        RunResult r = cli_t("info " + q(c.project.string()));
        INFO(bad);
        expect_clean_error(r, "project.json", "cache.frames");
    }
    std::ofstream(c.project / "project.json") << base;
    // --mask / --coc patterns given as flags are parsed too.
    RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 1 --coc " +
                        q((c.clip / "coc_%n.exr").string()));
    expect_clean_error(r, "coc_%n.exr", "bad frame pattern");

    // A video file that exists is a file, whatever '%' its name holds.
    for (const char* name : {"100%.mp4", "take_%d.mp4", "x_%s%n.mp4"}) {
        const fs::path v = make_mp4(c.dir / name);
        RunResult i = cli_t("info " + q(v.string()));
        INFO(i.output);
        CHECK(i.code == 0);
        CHECK(i.output.find("kind:     video") != std::string::npos);
    }
    // A missing one is "no such file", not a pattern.
    r = cli_t("info " + q((c.dir / "missing_%d.mp4").string()));
    expect_clean_error(r, "missing_%d.mp4", "no such file");
    r = cli_t("info " + q((c.clip / "input_%n.png").string()));
    expect_clean_error(r, "input_%n.png", "bad frame pattern");
}

TEST_CASE("JSON: depth bounded, errors name the file and the field") {
    const Clip c = make_clip("robust_json");
    const std::string base = file_bytes(c.project / "project.json");
    json j = json::parse(base);
    // 10^5 levels in "name", 2*10^5 in an unknown section.
    std::string text = base;
    text.replace(text.find("\"name\": ") + 8, std::string::npos,
                 std::string(100000, '[') + std::string(100000, ']') + "}");
    std::ofstream(c.project / "project.json") << text;
    RunResult r = cli_t("info " + q(c.project.string()));
    expect_clean_error(r, "project.json", "nested deeper than 64");
    text = base.substr(0, base.rfind('}')) + ", \"junk\": " + std::string(200000, '{') + "}";
    std::ofstream(c.project / "project.json") << text;
    r = cli_t("info " + q(c.project.string()));
    expect_clean_error(r, "project.json", "nested deeper than 64");

    struct Case {
        std::function<void(json&)> edit;
        const char* field;
    } cases[] = {
        {[](json& j) { j["version"] = 4294967297LL; }, "newer Refocus"},
        {[](json& j) { j["version"] = "1"; }, "'version'"},
        {[](json& j) { j["clip"]["width"] = 1e300; }, "clip.width"},
        {[](json& j) { j["clip"]["frames"] = 18446744073709551615ULL; }, "clip.frames"},
        {[](json& j) { j["source"]["format"] = 3; }, "source.format"},
        {[](json& j) {
             j["fit"] = {{"batch", -2147483648LL}};
         },
         "fit.batch"},
        {[](json& j) {
             j["fit"] = {{"minutes", "5"}};
         },
         "fit.minutes"},
        {[](json& j) {
             j["fit"] = {{"minutes", 1e308}};
         },
         "fit.minutes"},
        {[](json& j) {
             j["fit"] = {{"preset", 3}};
         },
         "fit.preset"},
        {[](json& j) { j["fit"] = 7; }, "'fit'"},
    };
    for (const auto& k : cases) {
        json m = j;
        k.edit(m);
        std::ofstream(c.project / "project.json") << m.dump(2);
        RunResult e = cli_t("info " + q(c.project.string()));
        expect_clean_error(e, "project.json", k.field);
    }
    // "minutes": null (an old build's NaN budget) reads as not set.
    json m = j;
    m["fit"] = {{"minutes", nullptr}, {"iters", 2}};
    std::ofstream(c.project / "project.json") << m.dump(2);
    r = cli_t("info " + q(c.project.string()));
    CHECK(r.code == 0);
}

TEST_CASE("budgets are validated where they enter") {
    const Clip c = make_clip("robust_budget");
    const std::string before = file_bytes(c.project / "project.json");
    for (const char* flags :
         {"--minutes 0", "--minutes -1", "--minutes nan", "--minutes inf", "--minutes 1e9",
          "--iters 0", "--iters 1.5", "--checkpoint-seconds nan", "--batch 0"}) {
        RunResult r = cli_t("fit " + q(c.project.string()) + " " + flags);
        INFO(flags);
        INFO(r.output);
        CHECK(r.code == 1);
        CHECK(r.output.find(std::string(flags).substr(0, std::string(flags).find(' '))) !=
              std::string::npos);
        CHECK(count_lines_with(r.output, "error:") == 1);
        CHECK(file_bytes(c.project / "project.json") == before);
    }
    RunResult r = cli_t("fit " + q(c.project.string()) + " --minutes nan");
    CHECK(r.output.find("(0, 10080]") != std::string::npos);
    r = cli_t("new " + q((c.clip / "input_%04d.png").string()) + " -o " +
              q((c.dir / "p2").string()) + " --fps inf");
    expect_clean_error(r, "--fps");
    r = cli_t("synth --scene tripod -o " + q((c.dir / "s").string()) + " --frames 1e10");
    CHECK(r.code == 1);
    CHECK(!fs::exists(c.dir / "s"));
}

TEST_CASE("project lock: one writer, readers free, stale locks taken over") {
    const Clip c = make_clip("robust_lock");
    {
        const auto held = ProjectLock::acquire(c.project, "test holder");
        CHECK(ProjectLock::holder(c.project).find("test holder") != std::string::npos);
        RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 1");
        expect_clean_error(r, "proj", "in use by another writer");
        CHECK(r.output.find("pid " + std::to_string(::getpid())) != std::string::npos);
        CHECK(r.output.find("test holder") != std::string::npos);
        r = cli_t("atlas " + q(c.project.string()) + " --clear");
        expect_clean_error(r, "proj", "in use");
        r = cli_t("info " + q(c.project.string()));  // a reader
        CHECK(r.code == 0);
    }
    CHECK(ProjectLock::holder(c.project).empty());
    // A stale file (its holder died: no flock on it) is taken over.
    std::ofstream(ProjectLock::file_of(c.project)) << "pid 999999: refocus fit\n";
    RunResult r = cli_t("atlas " + q(c.project.string()) + " --clear");
    INFO(r.output);
    CHECK(r.code == 0);
    // kill -9 of a holder releases the lock.
    r = run("(flock -o " + q(ProjectLock::file_of(c.project).string()) +
            " sleep 5 >/dev/null 2>&1 & sleep 0.5; " + REFOCUS_CLI + " atlas " +
            q(c.project.string()) + " --clear; kill -9 $!; sleep 0.2; " + REFOCUS_CLI + " atlas " +
            q(c.project.string()) + " --clear; echo rc=$?)");
    INFO(r.output);
    CHECK(count_lines_with(r.output, "in use") == 1);
    CHECK(r.output.find("atlas edits cleared") != std::string::npos);
    CHECK(r.output.find("rc=0") != std::string::npos);
}

TEST_CASE("silent wrong results are refused or fixed") {
    const fs::path dir = scratch_dir("robust_silent");
    std::vector<Image> frames;
    for (int i = 0; i < 4; ++i) frames.push_back(pattern_frame(32, 24, i));

    // A JPEG cut at half.
    fs::create_directories(dir / "jpg");
    for (int i = 0; i < 4; ++i) {
        const std::string p = (dir / "jpg" / ("f_000" + std::to_string(i) + ".jpg")).string();
        auto out = OIIO::ImageOutput::create(p);
        REQUIRE(out);
        OIIO::ImageSpec spec(32, 24, 3, OIIO::TypeDesc::UINT8);
        REQUIRE(out->open(p, spec));
        REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, frames[i].data()));
        out->close();
    }
    fs::resize_file(dir / "jpg" / "f_0002.jpg", fs::file_size(dir / "jpg" / "f_0002.jpg") / 2);
    RunResult r = cli_t("new " + q((dir / "jpg").string()) + " -o " + q((dir / "pj").string()));
    expect_clean_error(r, "f_0002.jpg", "truncated");
    CHECK(!fs::exists(dir / "pj"));

    // Gaps and duplicates in a folder.
    write_png_sequence(dir / "gap", frames);
    fs::remove(dir / "gap" / "frame_0002.png");
    r = cli_t("info " + q((dir / "gap").string()));
    expect_clean_error(r, "gap", "frame number 2 is missing");
    write_png_sequence(dir / "dup", frames);
    fs::copy_file(dir / "dup" / "frame_0003.png", dir / "dup" / "frame_03.png");
    r = cli_t("info " + q((dir / "dup").string()));
    expect_clean_error(r, "dup", "two files have frame number 3");

    // RGBA: alpha dropped, colour as stored (not premultiplied).
    fs::create_directories(dir / "rgba");
    std::vector<float> px(32 * 24 * 4);
    for (size_t i = 0; i < px.size(); i += 4) {
        px[i] = 0.8f;
        px[i + 1] = 0.4f;
        px[i + 2] = 0.2f;
        px[i + 3] = 0.5f;
    }
    for (int i = 0; i < 3; ++i) {
        const std::string p = (dir / "rgba" / ("f_000" + std::to_string(i) + ".png")).string();
        auto out = OIIO::ImageOutput::create(p);
        OIIO::ImageSpec spec(32, 24, 4, OIIO::TypeDesc::UINT8);
        spec.attribute("oiio:UnassociatedAlpha", 1);
        REQUIRE(out->open(p, spec));
        REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
        out->close();
    }
    r = cli_t("new " + q((dir / "rgba").string()) + " -o " + q((dir / "prgba").string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    const Image f = Project::load(dir / "prgba").read_frame(1);
    CHECK(f.at(3, 3, 0) == doctest::Approx(srgb_to_linear(204 / 255.0f)).epsilon(0.01));
    CHECK(f.at(3, 3, 1) == doctest::Approx(srgb_to_linear(102 / 255.0f)).epsilon(0.01));

    // Tiny clips refused up front with the minimum size.
    write_png_sequence(dir / "tiny", {pattern_frame(8, 8, 0), pattern_frame(8, 8, 1)});
    r = cli_t("new " + q((dir / "tiny").string()) + " -o " + q((dir / "ptiny").string()));
    expect_clean_error(r, "tiny", "at least 12x12");
    CHECK(!fs::exists(dir / "ptiny"));
}

TEST_CASE("an interrupted ingest leaves no project folder") {
    const fs::path dir = scratch_dir("robust_interrupt");
    // 100 copies of one 640x480 frame: an ingest of a few seconds, cheap to make.
    write_png_sequence(dir / "clip", {pattern_frame(640, 480, 0)});
    for (int i = 1; i < 100; ++i) {
        char name[32];
        std::snprintf(name, sizeof name, "frame_%04d.png", i);
        fs::copy_file(dir / "clip" / "frame_0000.png", dir / "clip" / name);
    }
    RunResult r;
    // SIGINT once half the frames are in (the progress line at 50), as Ctrl-C would.
    const fs::path log = dir / "log.txt";
    r = run("(" + std::string(REFOCUS_CLI) + " new " +
            q((dir / "clip" / "frame_%04d.png").string()) + " -o " + q((dir / "p").string()) +
            " > " + q(log.string()) + " 2>&1 & pid=$!; i=0; " +
            "while [ $i -lt 600 ] && ! grep -q 'ingest 50/' " + q(log.string()) +
            "; do sleep 0.02; i=$((i+1)); done; kill -INT $pid; wait $pid; echo rc=$?)");
    const std::string out = read_text_file(log);
    INFO(r.output);
    INFO(out);
    const bool finished = r.output.find("rc=0") != std::string::npos;
    if (finished) {
        MESSAGE("ingest finished before the interrupt");
        CHECK(fs::exists(dir / "p" / "project.json"));
    } else {
        CHECK(r.output.find("rc=1") != std::string::npos);
        CHECK(out.find("interrupted: no project was created") != std::string::npos);
        CHECK(!fs::exists(dir / "p"));
        CHECK(stray_temporaries(dir).empty());
    }
}
