// refocus-studio: the desktop application.
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>

#include "studio.h"
#include "util/allocator.h"
#include "util/threads.h"

int main(int argc, char** argv) {
    // See refocus_main.cpp: passive OpenMP waiting, set before libgomp loads.
    if (!std::getenv("OMP_WAIT_POLICY")) {
        setenv("OMP_WAIT_POLICY", "PASSIVE", 1);
        execv("/proc/self/exe", argv);
    }
    refocus::StudioOptions o;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "refocus-studio: %s needs a value\n", a.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--help" || a == "-h") {
            std::printf(
                "usage: refocus-studio [project-or-clip] [--frame N] [--size WxH]\n"
                "                      [--screenshot out.png --exit-after FRAMES] [--script "
                "steps.json]\n"
                "--exit-after counts frames drawn once the viewer shows its picture (30 s at "
                "most)\n"
                "--script runs a JSON list of actions (see ui/studio_script.h) and exits: 0 when\n"
                "every step passed.\n");
            return 0;
        } else if (a == "--screenshot") {
            o.screenshot = next();
        } else if (a == "--script") {
            o.script = next();
        } else if (a == "--exit-after") {
            o.exit_after = std::atoi(next().c_str());
        } else if (a == "--frame") {
            o.start_frame = std::atoi(next().c_str());
        } else if (a == "--size") {
            std::string s = next();
            if (std::sscanf(s.c_str(), "%dx%d", &o.width, &o.height) != 2) {
                std::fprintf(stderr, "refocus-studio: --size needs WxH\n");
                return 2;
            }
            o.size_given = true;
        } else if (!a.empty() && a[0] == '-') {
            std::fprintf(stderr, "refocus-studio: unknown option %s\n", a.c_str());
            return 2;
        } else {
            o.open_path = a;
        }
    }
    if (!o.screenshot.empty() && o.exit_after < 0) o.exit_after = 3;
    // Scripts and screenshots start from the default layout, so that they come out the same.
    o.remember_layout = o.script.empty() && o.screenshot.empty();
    try {
        refocus::tune_allocator();
        refocus::init_threads();
        return refocus::run_studio(o);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "refocus-studio: error: %s\n", e.what());
        return 1;
    }
}
