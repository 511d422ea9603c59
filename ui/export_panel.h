#pragma once
// The Export tab: passes, format, frame range and folder (typed or browsed); progress with
// cancel.
#include <nlohmann/json.hpp>

#include <string>

#include "file_browser.h"

namespace refocus {

struct StudioContext;

struct ExportPanelState {
    bool pass[11] = {true,  true,  false, false, false, false,
                     false, false, false, false, false};  // in the checkboxes' order
    int format = 0;
    int first = 0, last = -1;  // -1: the clip's last frame
    char out[1024] = {0};
    bool running = false;
    double started = 0.0;             // glfwGetTime() when the running export began
    int seen_in = -1, seen_out = -1;  // the timeline's in/out points the range last followed
    std::string result;               // what the last export wrote, or why it failed
    FileBrowser browser;              // the output folder's
};

// After a project opened: the whole clip, into <project>/export unless a folder was given.
void reset_export_panel(ExportPanelState& s, StudioContext& ctx);
// Starts an export on the worker: {"what": [pass, ...], "format": f, "out": dir, "first": a,
// "last": b} (the panel's Export button and the script's "export").
void start_export(ExportPanelState& s, StudioContext& ctx, const nlohmann::json& request);
void draw_export_panel(ExportPanelState& s, StudioContext& ctx);

}  // namespace refocus
