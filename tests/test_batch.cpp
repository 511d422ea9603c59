// refocus batch: a shot list validated as a whole, run N shots at once, re-run skips what is
// done, and a shot's outputs equal those of the same commands typed by hand.
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <thread>

#include "batch_util.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

RunResult cli_env(const std::string& env, const std::string& args) {
    return run(env + std::string(REFOCUS_CLI) + " " + args);
}

}  // namespace

TEST_CASE("batch: run two shots at once, skip them when run again, equal to commands by hand") {
    const fs::path root = scratch_dir("batch");
    for (const char* scene : {"rack", "tripod"}) {
        const auto r = cli(std::string("synth --scene ") + scene + " -o '" +
                           (root / scene).string() + "' --size 64x36 --frames 6");
        REQUIRE(r.code == 0);
    }
    const fs::path list = root / "shots.json";
    write(list, R"({"shots": [
      {"name": "sh010", "clip": "rack/input_%04d.png", "project": "p/sh010", "iters": 4,
       "set": {"fit.crop_px": 0}, "exports": [{"what": "sharp", "out": "out/sh010"}]},
      {"clip": "tripod/input_%04d.png", "project": "p/sh020", "iters": 4,
       "exports": [{"what": "sharp", "format": "mp4", "out": "out/sh020.mp4"}]}]})");
    auto r = cli("batch plan '" + list.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("refocus fit") != std::string::npos);
    // The same list as CSV plans the same commands.
    const fs::path csv = root / "shots.csv";
    write(csv,
          "name,clip,project,iters,set,exports\n"
          "sh010,rack/input_%04d.png,p/sh010,4,fit.crop_px=0,sharp:png:out/sh010\n"
          ",\"tripod/input_%04d.png\",p/sh020,4,,sharp:mp4:out/sh020.mp4\n");
    const auto rc = cli("batch plan '" + csv.string() + "'");
    INFO(rc.output);
    REQUIRE(rc.code == 0);
    CHECK(rc.output == r.output);

    r = cli("batch run '" + list.string() + "' --jobs 2");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("sh010            done") != std::string::npos);
    CHECK(r.output.find("sh020            done") != std::string::npos);
    CHECK(fs::exists(root / "out/sh010/sharp_0005.png"));
    CHECK(fs::exists(root / "out/sh020.mp4"));
    CHECK(fs::exists(root / "batch_logs/sh010.log"));

    // Again: nothing is done twice.
    r = cli("batch run '" + list.string() + "' --jobs 2");
    REQUIRE(r.code == 0);
    CHECK(r.output.find("sh010            skipped") != std::string::npos);
    CHECK(r.output.find("sh020            skipped") != std::string::npos);
    CHECK(r.output.find("] fit ") == std::string::npos);

    // The same shot typed by hand, with the batch's thread count (2 jobs on this machine's
    // cores): the same frames, byte for byte.
    const fs::path hand = root / "hand";
    REQUIRE(cli("new '" + (root / "rack/input_%04d.png").string() + "' -o '" + hand.string() + "'")
                .code == 0);
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    const std::string env = "REFOCUS_THREADS=" + std::to_string(std::max(1u, cores / 2)) + " ";
    REQUIRE(cli_env(env, "fit '" + hand.string() + "' --preset fast --iters 4 --set fit.crop_px=0")
                .code == 0);
    REQUIRE(cli_env(env, "export '" + hand.string() + "' --what sharp --format png --out '" +
                             (root / "hand_out").string() + "'")
                .code == 0);
    for (int t = 0; t < 6; ++t) {
        char name[32];
        std::snprintf(name, sizeof name, "sharp_%04d.png", t);
        INFO(name);
        CHECK(bytes_of(root / "out/sh010" / name) == bytes_of(root / "hand_out" / name));
    }

    r = cli("batch status '" + list.string() + "'");
    REQUIRE(r.code == 0);
    CHECK(r.output.find("sh020            done") != std::string::npos);
}

TEST_CASE("batch: a bad shot list is refused as a whole, naming the shot and the field") {
    const fs::path root = scratch_dir("batch_bad");
    REQUIRE(
        cli("synth --scene rack -o '" + (root / "c").string() + "' --size 64x36 --frames 4").code ==
        0);
    const fs::path list = root / "shots.json";
    const std::string good = R"({"clip": "c/input_%04d.png", "project": "p/a", "iters": 2})";
    struct Bad {
        std::string second, says;
    };
    const Bad bad[] = {
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "minutes": -1})", "\"minutes\""},
        {R"({"clip": "nowhere.mp4", "project": "p/b"})", "\"clip\" does not exist"},
        {R"({"clip": "c/input_%04d.png", "project": "p/a"})", "shot 1's project too"},
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "preset": "quick"})", "\"preset\""},
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "set": {"fit.nope": 1}})", "\"set\""},
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "exports": [{"what": "x", "out": "o"}]})",
         "unknown pass"},
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "colour": 1})", "\"colour\""},
        {R"({"clip": "c/input_%04d.png", "project": "p/b", "iters": 2, "minutes": 1})",
         "exclusive"},
    };
    for (const Bad& b : bad) {
        write(list, R"({"shots": [)" + good + ", " + b.second + "]}");
        const auto r = cli("batch run '" + list.string() + "'");
        INFO(b.second << "\n" << r.output);
        CHECK(r.code != 0);
        CHECK(r.output.find("shot 2") != std::string::npos);
        CHECK(r.output.find(b.says) != std::string::npos);
        CHECK(r.output.find("shots.json") != std::string::npos);
        CHECK_FALSE(fs::exists(root / "p/a"));  // nothing ran
    }
    const fs::path csv = root / "shots.csv";
    write(csv, "clip,project,iters\nc/input_%04d.png,p/a,2\nc/input_%04d.png,p/b\n");
    auto r = cli("batch plan '" + csv.string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("line 3 has 2 fields") != std::string::npos);
    write(csv, "clip,project,iters\nc/input_%04d.png,p/a,2\nc/input_%04d.png,p/b,two\n");
    r = cli("batch plan '" + csv.string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("shot 2 (b): \"iters\"") != std::string::npos);
    write(list, R"({"shots": []})");
    CHECK(cli("batch run '" + list.string() + "'").code != 0);
    CHECK(cli("batch run '" + list.string() + "' --jobs 0").code != 0);
}
