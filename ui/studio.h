#pragma once
#include <string>

namespace refocus {

struct StudioOptions {
    std::string open_path;   // project or clip to open at start (may be empty)
    std::string screenshot;  // write a PNG of the window after `exit_after` frames
    int exit_after = -1;     // close after this many rendered UI frames (-1: run until closed)
    int start_frame = 0;
    std::string script;  // a JSON list of actions to run, then exit (tests/gui/smoke.json)
    int width = 1280, height = 800;
    bool size_given = false;      // --size: not the remembered window size
    bool remember_layout = true;  // read and write the window's layout (layout.h)
};

// Runs the Refocus Studio window; returns the exit code.
int run_studio(const StudioOptions& opts);

}  // namespace refocus
