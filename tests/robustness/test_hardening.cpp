// The second round of hostile cases: values a flag may store load again, outputs never land on a
// project's own files or its inputs, damaged checkpoints and absurd input are refused, a full
// disk during a checkpoint fails cleanly, bounds on threads and radii, and clear messages.
// LibTorch's headers first: glog's CHECK must not replace doctest's.
#include "fit/fit_engine.h"
#include "session/fit_session.h"

#include <OpenImageIO/imageio.h>
#include <doctest/doctest.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <random>

#include "io/clip.h"
#include "io/image_file.h"
#include "project/project.h"
#include "robustness/robust_util.h"
#include "test_util.h"
#include "util/error.h"
#include "util/lock.h"
#include "util/threads.h"

using namespace refocus;
using namespace refocus::test;
using namespace refocus::robust;
using nlohmann::json;

namespace {

// A copy of a fitted project (its files, not links: the copy is damaged on purpose).
fs::path copy_project(const Clip& c, const fs::path& to) {
    fs::copy(c.project, to, fs::copy_options::recursive);
    fs::remove(to / ".lock");
    // The radius maps' path is relative to the project: made absolute for the copy.
    json pj = json::parse(read_text_file(to / "project.json"));
    pj["fit"]["coc"] = fs::absolute(c.clip / "coc_%04d.exr").string();
    std::ofstream(to / "project.json") << pj.dump(2);
    return to;
}

fs::path tensor_file(const fs::path& project) {
    const json j = json::parse(read_text_file(project / "fit" / "checkpoint.json"));
    return project / "fit" / j["tensors"].get<std::string>();
}

// Writes a float EXR sequence <dir>/f_%04d.exr of pattern frames; `edit` may change frame 1.
void write_exr_sequence(const fs::path& dir, int w, int h, int frames,
                        const std::function<void(Image&)>& edit) {
    fs::create_directories(dir);
    for (int t = 0; t < frames; ++t) {
        Image f = pattern_frame(w, h, t);
        if (t == 1 && edit) edit(f);
        char name[32];
        std::snprintf(name, sizeof name, "f_%04d.exr", t);
        write_image_file((dir / name).string(), f, PixelFormat::ExrFloat, false);
    }
}

// The pid of a process that has ended (for a killed command's temporary).
long dead_pid() {
    RunResult r = run("sh -c 'echo $$'");
    return std::stol(r.output);
}

}  // namespace

TEST_CASE("a value a flag stores always loads again; the loader names the flag") {
    const Clip c = make_clip("hard_flags");
    const std::string before = file_bytes(c.project / "project.json");
    for (const char* flags : {"--batch 99999", "--seed -1", "--seed 1e30",
                              "--seed 18446744073709551615", "--batch 2.5"}) {
        RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 3 " + flags);
        INFO(flags);
        expect_clean_error(r, std::string(flags).substr(0, std::string(flags).find(' ')));
        CHECK(file_bytes(c.project / "project.json") == before);
    }
    RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 3 --batch 99999");
    CHECK(r.output.find("0..4096") != std::string::npos);
    // In range: stored, and every command opens the project again.
    r = cli_t("fit " + q(c.project.string()) + " --iters 2 --seed 9007199254740991 --batch 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(cli_t("info " + q(c.project.string())).code == 0);
    r = cli_t("fit " + q(c.project.string()) + " --iters 3 --resume");
    INFO(r.output);
    CHECK(r.code == 0);
    // A hand-edited value: the loader's message names the field and the flag that sets it.
    json pj = json::parse(read_text_file(c.project / "project.json"));
    pj["fit"]["batch"] = 99999;
    std::ofstream(c.project / "project.json") << pj.dump(2);
    r = cli_t("info " + q(c.project.string()));
    expect_clean_error(r, "project.json", "fit.batch");
    CHECK(r.output.find("--batch") != std::string::npos);
}

TEST_CASE("an export never lands on the project's own files or on its inputs") {
    const Clip& c = fitted("hard_fitted");
    const fs::path p = c.project;
    const std::map<std::string, std::string> keep = {
        {"project.json", file_bytes(p / "project.json")},
        {"fit/checkpoint.json", file_bytes(p / "fit" / "checkpoint.json")},
        {"frames/frame_0003.exr", file_bytes(p / "frames" / "frame_0003.exr")},
        {"clip/input_0001.png", file_bytes(c.clip / "input_0001.png")}};
    const fs::path pt = tensor_file(p);
    const std::string pt_bytes = file_bytes(pt);
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"--what sharp --format mp4 --out " + q((p / "project.json").string()), "project.json"},
        {"--what sharp --format mp4 --out " + q(pt.string()), "fit"},
        {"--what sharp --format mp4 --out " + q((p / "frames" / "frame_0003.exr").string()),
         "frames"},
        {"--what sharp --out " + q((p / "frames").string()), "frames"},
        {"--what all --out " + q((p / "fit").string()), "fit"},
        {"--what sharp --out " + q((p / "prep" / "x").string()), "prep"},
        {"--what sharp --format mp4 --out " + q((p / "." / "fit" / ".." / "project.json").string()),
         "project.json"},
        {"--what sharp --out " + q(c.clip.string()), "source frames"},
        {"--what sharp --format mp4 --out " + q((c.clip / "coc_0000.exr").string()),
         "source frames"}};
    for (const auto& [flags, problem] : cases) {
        RunResult r = cli_t("export " + q(p.string()) + " " + flags);
        INFO(flags);
        expect_clean_error(r, "", problem);
        CHECK(r.output.find("choose another --out") != std::string::npos);
    }
    for (const auto& [name, bytes] : keep)
        CHECK(file_bytes(name.rfind("clip/", 0) == 0 ? c.dir / name : p / name) == bytes);
    CHECK(file_bytes(pt) == pt_bytes);
    // A symbolic link to the project is seen through.
    const fs::path link = scratch_dir("hard_link") / "l";
    fs::create_directory_symlink(fs::absolute(p), link);
    RunResult r = cli_t("export " + q(p.string()) + " --what sharp --format mp4 --out " +
                        q((link / "project.json").string()));
    expect_clean_error(r, "", "project.json");
    CHECK(file_bytes(p / "project.json") == keep.at("project.json"));
}

TEST_CASE("a damaged checkpoint is refused by every command; info says so") {
    const Clip& c = fitted("hard_fitted");
    const fs::path work = scratch_dir("hard_ckpt");
    // Bytes flipped inside the tensor file.
    const fs::path flip = copy_project(c, work / "flip");
    {
        const fs::path pt = tensor_file(flip);
        std::string bytes = file_bytes(pt);
        std::mt19937 rng(7);
        for (int i = 0; i < 2000; ++i) bytes[bytes.size() / 4 + rng() % (bytes.size() / 2)] ^= 0x5a;
        std::ofstream(pt, std::ios::binary) << bytes;
    }
    RunResult r =
        cli_t("export " + q(flip.string()) + " --what sharp --out " + q((work / "o1").string()));
    expect_clean_error(r, ".pt", "damaged");
    CHECK(!fs::exists(work / "o1"));
    r = cli_t("fit " + q(flip.string()) + " --resume --iters 8");
    expect_clean_error(r, ".pt", "damaged");
    r = cli_t("info " + q(flip.string()));
    INFO(r.output);
    CHECK(r.code == 0);
    CHECK(r.output.find("checkpoint cannot be used") != std::string::npos);
    CHECK(r.output.find("holds:    fit\n") == std::string::npos);
    // A fresh fit replaces it.
    r = cli_t("fit " + q(flip.string()) + " --iters 2");
    INFO(r.output);
    CHECK(r.code == 0);
    CHECK(cli_t("info " + q(flip.string())).output.find("holds:    fit\n") != std::string::npos);

    // The running residual damaged: named where its frames are read; info says so.
    const fs::path resid = copy_project(c, work / "resid");
    {
        const json jr = json::parse(read_text_file(resid / "fit" / "checkpoint.json"));
        const fs::path rf = resid / "fit" / jr.at("residual").get<std::string>();
        std::string bytes = file_bytes(rf);
        for (size_t i = bytes.size() / 2; i < bytes.size() / 2 + 16; ++i) bytes[i] ^= 0x5a;
        std::ofstream(rf, std::ios::binary) << bytes;
    }
    r = cli_t("export " + q(resid.string()) + " --what sharp --out " + q((work / "o4").string()));
    expect_clean_error(r, ".resid", "damaged");
    r = cli_t("info " + q(resid.string()));
    CHECK(r.output.find("checkpoint cannot be used") != std::string::npos);

    // checkpoint.json edited by hand: its own checksum.
    const fs::path edit = copy_project(c, work / "edit");
    json j = json::parse(read_text_file(edit / "fit" / "checkpoint.json"));
    j["step"] = j["step"].get<int>() + 1;
    std::ofstream(edit / "fit" / "checkpoint.json") << j.dump(1);
    r = cli_t("export " + q(edit.string()) + " --what sharp --out " + q((work / "o2").string()));
    expect_clean_error(r, "checkpoint.json", "checksum");

    // The tensor file deleted.
    const fs::path gone = copy_project(c, work / "gone");
    fs::remove(tensor_file(gone));
    r = cli_t("export " + q(gone.string()) + " --what sharp --out " + q((work / "o3").string()));
    expect_clean_error(r, ".pt", "missing");
    CHECK(cli_t("info " + q(gone.string())).output.find("missing") != std::string::npos);
}

TEST_CASE("absurd finite input is refused as Inf is; --nonfinite clean clamps it") {
    const fs::path dir = scratch_dir("hard_absurd");
    write_exr_sequence(dir / "big", 48, 32, 4, [](Image& f) {
        for (int y = 5; y < 15; ++y)
            for (int x = 5; x < 15; ++x)
                for (int ch = 0; ch < 3; ++ch) f.at(x, y, ch) = 1e30f;
    });
    RunResult r = cli_t("new " + q((dir / "big").string()) + " -o " + q((dir / "p").string()));
    expect_clean_error(r, "f_0001.exr", "out-of-range");
    CHECK(r.output.find("--nonfinite clean") != std::string::npos);
    CHECK(!fs::exists(dir / "p"));
    r = cli_t("new " + q((dir / "big").string()) + " -o " + q((dir / "p").string()) +
              " --nonfinite clean");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const Image f = Project::load(dir / "p").read_frame(1);
    CHECK(f.at(8, 8, 0) <= kMaxLinearValue);
    r = cli_t("fit " + q((dir / "p").string()) + " --iters 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli_t("export " + q((dir / "p").string()) + " --what all --out " +
              q((dir / "all").string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    for (const auto& e : fs::recursive_directory_iterator(dir / "all"))
        if (e.path().extension() == ".exr")
            CHECK(count_nonfinite(read_image_file(e.path().string(), false).image) == 0);
}

TEST_CASE("radius maps: a NaN or an absurd radius is refused with what to do") {
    const Clip c = make_clip("hard_coc");
    // Six 48x32 maps of `radius` in <dir>/coc_%04d.exr, with a NaN in frame 2 when `nan`.
    auto write_maps = [](const fs::path& dir, float radius, bool nan) {
        fs::create_directories(dir);
        for (int t = 0; t < 6; ++t) {
            Image m(48, 32, 1);
            for (float& v : m.pixels) v = radius;
            if (nan && t == 2) m.at(3, 3, 0) = NAN;
            char name[32];
            std::snprintf(name, sizeof name, "coc_%04d.exr", t);
            write_image_file((dir / name).string(), m, PixelFormat::ExrFloat, false);
        }
        return q((dir / "coc_%04d.exr").string());
    };
    const auto t0 = std::chrono::steady_clock::now();
    RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 2 --coc " +
                            write_maps(c.dir / "big", 1000, false),
                        60);
    expect_clean_error(r, "coc_0000.exr");
    CHECK(r.output.find("at most 24 px") != std::string::npos);
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(30));
    // Beyond 1e4 it is refused as absurd, as any image value is.
    r = cli_t("fit " + q(c.project.string()) + " --iters 2 --coc " +
              write_maps(c.dir / "huge", 1e6f, false));
    expect_clean_error(r, "coc_0000.exr", "--coc");
    r = cli_t("fit " + q(c.project.string()) + " --iters 2 --coc " +
              write_maps(c.dir / "nan", 1.0f, true));
    expect_clean_error(r, "coc_0002.exr", "--coc");
    CHECK(r.output.find("--nonfinite") == std::string::npos);
}

TEST_CASE("a full disk while a checkpoint is written: exit 1, nothing half-written") {
    const Clip c = make_clip("hard_disk_src");
    SmallDisk disk(scratch_dir("hard_disk") / "disk", 4096);
    if (!disk.ok) return;
    const fs::path p = disk.dir / "proj";
    fs::copy(c.project, p, fs::copy_options::recursive);
    // The preparation first (cached), so that the checkpoint is the first write of the next fit.
    RunResult r = cli_t("fit " + q(p.string()) + " --iters 1");
    INFO(r.output);
    REQUIRE(r.code == 0);
    fs::remove_all(p / "fit");
    const std::string before = file_bytes(p / "project.json");
    disk.fill(4096);
    r = cli_t("fit " + q(p.string()) + " --iters 2");
    expect_clean_error(r, "checkpoint_2.pt", "No space left on device");
    CHECK(r.code == 1);
    CHECK(file_bytes(p / "project.json") == before);
    CHECK(stray_temporaries(disk.dir).empty());
    CHECK(ProjectLock::holder(p).empty());
    CHECK(r.output.find("c10::Error") == std::string::npos);
}

TEST_CASE("REFOCUS_THREADS is bounded; a bad value warns and the command runs") {
    std::string warning;
    CHECK(threads_from_env(nullptr, 2, &warning) == 2);
    CHECK(warning.empty());
    CHECK(threads_from_env("3", 2, &warning) == 3);
    CHECK(warning.empty());
    for (const char* bad : {"99999", "2000", "0", "-1", "abc", "", "4x", "9999999999999999999"}) {
        warning.clear();
        INFO(bad);
        CHECK(threads_from_env(bad, 2, &warning) == 2);
        CHECK(warning.find("REFOCUS_THREADS") != std::string::npos);
        CHECK(warning.find("1..8") != std::string::npos);
    }
    const Clip c = make_clip("hard_threads");
    for (const char* bad : {"99999", "abc"}) {
        const auto t0 = std::chrono::steady_clock::now();
        RunResult r = run(std::string("REFOCUS_THREADS=") + bad + " timeout 30 " + REFOCUS_CLI +
                          " info " + q(c.project.string()));
        INFO(r.output);
        CHECK(r.code == 0);
        CHECK(r.output.find("warning: REFOCUS_THREADS") != std::string::npos);
        CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(20));
    }
}

TEST_CASE("videos: --fps replaces the rate; a count estimated from the duration is no refusal") {
    const fs::path dir = scratch_dir("hard_video");
    const fs::path mp4 = make_mp4(dir / "v.mp4");
    RunResult r = cli_t("new " + q(mp4.string()) + " -o " + q((dir / "p").string()) + " --fps 5");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(Project::load(dir / "p").fps == doctest::Approx(5.0));
    CHECK(r.output.find("replaces the video's own frame rate") != std::string::npos);
    // A variable-frame-rate Matroska file: 16 frames, the second half 3x as long each.
    const fs::path mkv = dir / "vfr.mkv";
    r =
        run("ffmpeg -nostdin -loglevel error -f lavfi -i testsrc=size=64x48:rate=10 -frames:v 16 "
            "-vf \"setpts='if(lt(N,8),N,8+(N-8)*3)/10/TB'\" -fps_mode vfr -c:v libx264 -y " +
            q(mkv.string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli_t("new " + q(mkv.string()) + " -o " + q((dir / "pv").string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(Project::load(dir / "pv").frames == 16);
}

TEST_CASE("a very wide clip is refused at ingest; one at the limit fits") {
    const fs::path dir = scratch_dir("hard_wide");
    std::vector<Image> frames, edge;
    for (int t = 0; t < 4; ++t) frames.push_back(pattern_frame(2000, 12, t));
    write_png_sequence(dir / "wide", frames);
    RunResult r = cli_t("new " + q((dir / "wide").string()) + " -o " + q((dir / "p").string()));
    expect_clean_error(r, "wide", "more than 12 times as wide as high");
    CHECK(!fs::exists(dir / "p"));
    for (int t = 0; t < 4; ++t) edge.push_back(pattern_frame(192, 16, t));
    write_png_sequence(dir / "edge", edge);
    r = cli_t("new " + q((dir / "edge").string()) + " -o " + q((dir / "pe").string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli_t("fit " + q((dir / "pe").string()) + " --iters 2", 120);
    INFO(r.output);
    CHECK(r.code == 0);
    // A thin small clip: OpenCV's DIS flow crashed on a short side under 32 px (prep_detail::
    // dis_calc upsamples such frames).
    std::vector<Image> thin;
    for (int t = 0; t < 4; ++t) thin.push_back(pattern_frame(48, 12, t));
    write_png_sequence(dir / "thin", thin);
    r = cli_t("new " + q((dir / "thin").string()) + " -o " + q((dir / "pt").string()));
    REQUIRE(r.code == 0);
    r = cli_t("fit " + q((dir / "pt").string()) + " --iters 2", 120);
    INFO(r.output);
    CHECK(r.code == 0);
}

TEST_CASE("messages: empty paths, --what all, unknown flags, plain files, --help") {
    const Clip& c = fitted("hard_fitted");
    const fs::path work = scratch_dir("hard_msgs");
    RunResult r = cli_t("new " + q((c.clip / "input_%04d.png").string()) + " -o ''");
    expect_clean_error(r, "-o");
    CHECK(r.output.find("filesystem error") == std::string::npos);
    r = cli_t("export " + q(c.project.string()) + " --what all --format mp4 --out " +
              q((work / "x.mp4").string()));
    expect_clean_error(r, "x.mp4", "--what all writes a folder");
    r = cli_t("export " + q(c.project.string()) + " --what sharp --out " +
              q((work / "o").string()) + " --frobnicate");
    expect_clean_error(r, "--frobnicate", "unknown option");
    r = cli_t("export " + q(c.project.string()) + " --what sharp --out");
    expect_clean_error(r, "--out", "needs a value");
    std::ofstream(work / "plain.txt") << "hello";
    r = cli_t("info " + q((work / "plain.txt").string()));
    CHECK(r.code == 1);
    r = cli_t("export " + q((work / "plain.txt").string()) + " --what sharp --out " +
              q((work / "o").string()));
    expect_clean_error(r, "plain.txt", "is not a project");
    fs::create_directories(work / "empty");
    r = cli_t("fit " + q((work / "empty").string()) + " --iters 1");
    expect_clean_error(r, "empty", "is not a project");
    for (const char* cmd : {"new", "info", "fit", "export", "atlas", "synth", "bench"}) {
        r = cli_t(std::string(cmd) + " --help");
        INFO(cmd);
        INFO(r.output);
        CHECK(r.code == 0);
        CHECK(r.output.find(std::string("usage: refocus ") + cmd) != std::string::npos);
    }
}

TEST_CASE("a killed command's temporaries are removed by the next one that writes there") {
    const Clip& c = fitted("hard_fitted");
    const fs::path work = scratch_dir("hard_stale");
    const long pid = dead_pid();
    const std::string tag = ".tmp-" + std::to_string(pid) + "-0";
    fs::create_directories(work / "seq" / (".staging-sharp" + tag));
    std::ofstream(work / "seq" / (".staging-sharp" + tag) / "sharp_0000.png") << "partial";
    std::ofstream(work / (".v" + tag + ".mp4")) << "partial";
    // A live process's temporary stays (this test's own pid).
    const std::string live = ".staging-x.tmp-" + std::to_string(::getpid()) + "-0";
    fs::create_directories(work / "seq" / live);
    RunResult r = cli_t("export " + q(c.project.string()) + " --what sharp --out " +
                        q((work / "seq").string()));
    REQUIRE(r.code == 0);
    CHECK(!fs::exists(work / "seq" / (".staging-sharp" + tag)));
    CHECK(fs::exists(work / "seq" / live));
    r = cli_t("export " + q(c.project.string()) + " --what sharp --format mp4 --out " +
              q((work / "v.mp4").string()));
    REQUIRE(r.code == 0);
    CHECK(!fs::exists(work / (".v" + tag + ".mp4")));
    fs::create_directories(work / (".p" + tag) / "frames");  // a killed ingest's folder
    r = cli_t("new " + q((c.clip / "input_%04d.png").string()) + " -o " + q((work / "p").string()));
    REQUIRE(r.code == 0);
    CHECK(!fs::exists(work / (".p" + tag)));
}

TEST_CASE("a diverging fit stops before its update; no export writes a NaN") {
    // The rule: not finite, or 100x the running median once 8 steps are seen.
    std::deque<double> recent;
    CHECK(loss_divergence(recent, NAN).find("NaN") != std::string::npos);
    CHECK(loss_divergence(recent, 1e9).empty());  // too few steps to judge
    for (int i = 0; i < 10; ++i) recent.push_back(0.05 - 0.001 * i);
    CHECK(loss_divergence(recent, 0.5).empty());
    CHECK(loss_divergence(recent, 4.0).empty());
    CHECK(loss_divergence(recent, 6e8).find("diverging") != std::string::npos);

    FitOptions o;
    o.preset = "fast";
    o.iters = 40;
    FitEngine e(tiny_two_layer_data(4), o);
    for (int i = 0; i < 10; ++i) e.step();
    const fs::path dir = scratch_dir("hard_diverge");
    e.save_checkpoint(dir / "fit");
    const std::string saved = file_bytes(dir / "fit" / "checkpoint.json");
    {
        torch::NoGradGuard g;
        std::lock_guard<std::mutex> lock(e.model_mutex());
        for (auto& [name, t] : e.model().state())
            if (name.rfind("bg_level", 0) == 0) t.fill_(NAN);
    }
    const int64_t step = e.snapshot().step;
    CHECK_THROWS_WITH_AS(e.step(), doctest::Contains("the last checkpoint"), Error);
    CHECK(e.snapshot().step == step);
    CHECK(file_bytes(dir / "fit" / "checkpoint.json") == saved);
    // Export refuses the NaN frames and leaves nothing behind.
    ExportOptions eo;
    CHECK_THROWS_WITH_AS(export_pass(e, ExportPass::Sharp, "png", (dir / "out").string(), eo),
                         doctest::Contains("NaN/Inf"), Error);
    CHECK((!fs::exists(dir / "out") || fs::is_empty(dir / "out")));
    CHECK_THROWS_WITH_AS(export_pass(e, ExportPass::Atlas, "exr", (dir / "atlas").string(), eo),
                         doctest::Contains("NaN/Inf"), Error);
}
