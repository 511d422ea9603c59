#include "robustness/robust_util.h"

#include <cstring>
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
#include "test_util.h"
#include "util/error.h"
#include "util/lock.h"

using namespace refocus;
using namespace refocus::test;
using nlohmann::json;

namespace refocus::robust {

// Single-quoted for sh.
std::string q(const std::string& s) {
    std::string out = "'";
    for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return out + "'";
}

// The CLI under a timeout: 124 is a hang, >= 128 a signal (crash).
RunResult cli_t(const std::string& args, int seconds) {
    return run("timeout -k 5 " + std::to_string(seconds) + " " + std::string(REFOCUS_CLI) + " " +
               args);
}

int count_lines_with(const std::string& text, const std::string& what) {
    int n = 0;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);)
        if (line.find(what) != std::string::npos) ++n;
    return n;
}

// A failure is one "error:" line naming `file`, no raw library exception, no crash.
void expect_clean_error(const RunResult& r, const std::string& file, const std::string& problem) {
    INFO(r.output);
    CHECK(r.code == 1);
    CHECK(count_lines_with(r.output, "error:") == 1);
    CHECK(r.output.find(file) != std::string::npos);
    CHECK(r.output.find("[json.exception") == std::string::npos);
    if (!problem.empty()) CHECK(r.output.find(problem) != std::string::npos);
}

std::string file_bytes(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
}

Clip make_clip(const std::string& name, const std::string& size) {
    Clip c;
    c.dir = scratch_dir(name);
    c.clip = c.dir / "clip";
    RunResult r = cli_t("synth --quiet --scene tripod -o " + q(c.clip.string()) + " --size " +
                        size + " --frames 6 --seed 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    c.project = c.dir / "proj";
    r = cli_t("new " + q((c.clip / "input_%04d.png").string()) + " -o " + q(c.project.string()));
    INFO(r.output);
    REQUIRE(r.code == 0);
    return c;
}

// One fitted project shared by the export cases (a fit is the costly part).
const Clip& fitted(const std::string& name) {
    static Clip c = [&] {
        Clip c = make_clip(name);
        RunResult r = cli_t("fit " + q(c.project.string()) + " --iters 2 --coc " +
                                q((c.clip / "coc_%04d.exr").string()),
                            300);
        INFO(r.output);
        REQUIRE(r.code == 0);
        return c;
    }();
    return c;
}

// An mp4 of a few frames.
fs::path make_mp4(const fs::path& path) {
    ClipWriter w(path.string(), "v", ClipFormat::Mp4);
    for (int i = 0; i < 4; ++i) w.write(pattern_frame(32, 32, i));
    w.finish();
    return path;
}

SmallDisk::SmallDisk(const fs::path& d, int kib) : dir(d) {
    fs::create_directories(d);
    const std::string opts = "size=" + std::to_string(kib) + "k";
    ok = ::mount("tmpfs", d.c_str(), "tmpfs", 0, opts.c_str()) == 0;
    if (!ok)
        MESSAGE("cannot mount a small tmpfs here (" << std::strerror(errno)
                                                    << "): full-disk case skipped");
}
SmallDisk::~SmallDisk() {
    if (ok) ::umount2(dir.c_str(), MNT_DETACH);
}

void SmallDisk::fill(long keep) {
    std::ofstream f(dir / "ballast", std::ios::binary);
    std::string block(1024, 'x');
    for (int i = 0; i < 100000 && f; ++i) f.write(block.data(), block.size());
    f.close();
    fs::resize_file(dir / "ballast",
                    std::max<long>(0, long(fs::file_size(dir / "ballast")) - keep));
}

// One "error:" line naming `file`, no raw library exception.
bool one_line_naming(const std::string& out, const std::string& file) {
    return count_lines_with(out, "error:") == 1 && out.find(file) != std::string::npos &&
           out.find("[json.exception") == std::string::npos;
}

// Project::load (what `refocus info` does) in a forked child under a timeout.
Outcome load_in_child(const fs::path& dir, int seconds) {
    int fds[2];
    REQUIRE(::pipe(fds) == 0);
    const pid_t pid = ::fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
        ::close(fds[0]);
        std::string msg;
        int rc = 0;
        try {
            const Project p = Project::load(dir);
            msg = "loaded " + p.name + "\n";
        } catch (const std::exception& e) {
            std::string what = e.what();
            msg = "refocus info: error: " + what + "\n";
            rc = 1;
        }
        const ssize_t w = ::write(fds[1], msg.data(), std::min<size_t>(msg.size(), 60000));
        (void)w;
        ::_exit(rc);
    }
    ::close(fds[1]);
    Outcome o;
    const auto t0 = std::chrono::steady_clock::now();
    int status = 0;
    for (;;) {
        if (::waitpid(pid, &status, WNOHANG) == pid) break;
        if (std::chrono::steady_clock::now() - t0 > std::chrono::seconds(seconds)) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, &status, 0);
            o.rc = 124;
            break;
        }
        ::usleep(1000);
    }
    char buf[4096];
    for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) o.out.append(buf, size_t(n));
    ::close(fds[0]);
    if (o.rc != 124) o.rc = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    return o;
}

std::vector<std::string> stray_temporaries(const fs::path& dir) {
    std::vector<std::string> found;
    for (const auto& e : fs::recursive_directory_iterator(dir))
        if (e.path().filename().string().find(".tmp-") != std::string::npos)
            found.push_back(e.path().string());
    return found;
}

}  // namespace refocus::robust
