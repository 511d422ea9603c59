// refocus batch submit on a real Slurm: a one-machine cluster on loopback
// (tools/slurm/local_cluster.sh), three tiny shots (one as two windows) as job arrays, a window
// requeued mid-fit, the stitching exports after the fits;
// every output equals the same list run by `batch run`, byte for byte (fixed-step fits, one
// thread each). Exits 77 (CTest: skipped, with the reason printed) where the daemons cannot
// start: not root, Slurm or munge not installed.
#include <doctest/doctest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iterator>
#include <nlohmann/json.hpp>
#include <thread>

#include "io/image_file.h"
#include "batch_util.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

std::string sh(const fs::path& p) {
    return "'" + p.string() + "'";
}

// The cluster, stopped however the test ends.
struct Cluster {
    fs::path dir;
    ~Cluster() { run("bash " + sh(script()) + " stop " + sh(dir)); }
    static fs::path script() {
        return fs::path(REFOCUS_SOURCE_DIR) / "tools/slurm/local_cluster.sh";
    }
};

void wait_for(const std::function<bool()>& done, double seconds, const char* what) {
    const auto t0 = std::chrono::steady_clock::now();
    while (!done()) {
        if (std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(seconds))
            FAIL("timed out waiting for " << what);
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
    }
}

std::string squeue() {
    return run("squeue -h -r -o '%i %T %r'").output;
}

}  // namespace

TEST_CASE("batch submit: a Slurm job array, a task requeued mid-fit, outputs equal batch run's") {
    const fs::path root = scratch_dir("batch_slurm");
    Cluster cluster{root / "cluster"};
    const auto up = run("bash " + sh(Cluster::script()) + " start " + sh(cluster.dir));
    if (up.code == 3) {
        std::printf("test_batch_slurm: SKIPPED, no Slurm here: %s\n", up.output.c_str());
        std::fflush(stdout);
        std::_Exit(77);
    }
    INFO(up.output);
    REQUIRE(up.code == 0);
    setenv("SLURM_CONF", (cluster.dir / "slurm.conf").c_str(), 1);

    for (const char* scene : {"rack", "tripod", "pan"}) {
        const auto r = cli(std::string("synth --scene ") + scene + " -o " + sh(root / scene) +
                           " --size 64x36 --frames " + (scene[0] == 'p' ? "8" : "6"));
        REQUIRE(r.code == 0);
    }
    // The third shot is fitted as two windows (frames 0..4 and 3..7), each long enough to be
    // requeued while it trains; its exports wait for both.
    auto list_text = [](const std::string& p, const std::string& out) {
        return R"({"shots": [
          {"name": "sh010", "clip": "rack/input_%04d.png", "project": ")" +
               p + R"(/sh010",
           "iters": 30, "exports": [{"what": "sharp", "out": ")" +
               out + R"(/sh010"}]},
          {"name": "sh020", "clip": "tripod/input_%04d.png", "project": ")" +
               p + R"(/sh020",
           "iters": 30, "exports": [{"what": "sharp", "format": "exr", "out": ")" +
               out + R"(/sh020"}]},
          {"name": "sh030", "clip": "pan/input_%04d.png", "project": ")" +
               p + R"(/sh030",
           "iters": 600, "window": 6, "overlap": 2, "exports": [{"what": "sharp", "out": ")" +
               out + R"(/sh030"}]}]})";
    };
    const fs::path list = root / "shots.json", here = root / "here.json";
    write(list, list_text("slurm", "out_slurm"));
    write(here, list_text("here", "out_here"));

    auto r = cli("batch submit " + sh(list) + " --cpus 1 --dry-run");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("#SBATCH --array=0-3") != std::string::npos);  // 2 shots, 2 windows
    CHECK(r.output.find("units=( 0:-1 1:-1 2:0 2:1 )") != std::string::npos);
    CHECK(r.output.find("#SBATCH --dependency=afterok:<fits>") != std::string::npos);
    CHECK(r.output.find("#SBATCH --requeue") != std::string::npos);
    CHECK(!fs::exists(root / "batch_slurm"));

    r = cli("batch submit " + sh(list) + " --cpus 1");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const auto rec = nlohmann::json::parse(bytes_of(root / "batch_slurm/shots.json"));
    REQUIRE(rec["arrays"].size() == 2);
    const std::string job = rec["arrays"][0]["job"].get<std::string>();
    const std::string stitch = rec["arrays"][1]["job"].get<std::string>();
    REQUIRE(rec["arrays"][0]["units"][3] == nlohmann::json::array({2, 1, "sh030"}));

    // Requeue sh030's second window once its fit trains: Slurm sends SIGTERM, the fit
    // checkpoints and stops.
    const fs::path log = root / "batch_logs/sh030_w01.log";
    wait_for([&] { return bytes_of(log).find("\nfitting ") != std::string::npos; }, 300,
             "sh030 w01's fit to start");
    REQUIRE(run("scontrol requeue " + job + "_3").code == 0);
    // A requeued task waits two minutes before it is eligible; let it start now.
    wait_for([&] { return squeue().find(job + "_3 PENDING") != std::string::npos; }, 60,
             "the requeued task to be pending");
    REQUIRE(run("scontrol update JobId=" + job + "_3 StartTime=now").code == 0);
    const auto status = cli("batch status " + sh(list));
    INFO(status.output);
    wait_for(
        [&] {
            const std::string q = squeue();
            return q.find(job + "_") == std::string::npos &&
                   q.find(stitch + "_") == std::string::npos;
        },
        // Generous: the suite runs beside it (ctest -j) and Slurm's tasks share those cores; a
        // loaded 2-core machine once took over 240 s here.
        600, "both arrays to finish");

    const std::string slog = bytes_of(root / ("batch_logs/slurm_" + job + "_3.log"));
    INFO(slog);
    CHECK(slog.find("fit stopped") != std::string::npos);
    CHECK(slog.find("--resume") != std::string::npos);
    CHECK(bytes_of(log).find("resumed at step") != std::string::npos);
    CHECK(bytes_of(root / ("batch_logs/slurm_" + stitch + "_0.log")).find("export") !=
          std::string::npos);
    r = cli("batch status " + sh(list));
    INFO(r.output);
    CHECK(r.output.find("sh030            done") != std::string::npos);
    CHECK(r.output.find(" slurm ") != std::string::npos);

    // The same list here, one thread a shot as on Slurm: the same bytes.
    const int cores = std::max(1u, std::thread::hardware_concurrency());
    r = cli("batch run " + sh(here) + " --jobs " + std::to_string(cores));
    INFO(r.output);
    REQUIRE(r.code == 0);
    int compared = 0;
    for (const auto& e : fs::recursive_directory_iterator(root / "out_here")) {
        if (!e.is_regular_file()) continue;
        const fs::path rel = fs::relative(e.path(), root / "out_here");
        INFO(rel.string());
        const fs::path other = root / "out_slurm" / rel;
        if (rel.extension() == ".exr")  // the header holds the time it was written
            CHECK(read_image_file(e.path().string()).image.pixels ==
                  read_image_file(other.string()).image.pixels);
        else
            CHECK(bytes_of(e.path()) == bytes_of(other));
        ++compared;
    }
    CHECK(compared == 20);

    // Submitting again finds nothing to do.
    r = cli("batch submit " + sh(list) + " --cpus 1");
    CHECK(r.code == 0);
    CHECK(r.output.find("nothing submitted") != std::string::npos);
}
