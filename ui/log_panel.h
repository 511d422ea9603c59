#pragma once
// The Log tab: the UI's frame times and the fit worker's log. It keeps no state of its own: the
// frame times are measured by the window loop and the viewer (StudioContext::times).

namespace refocus {

struct StudioContext;

void draw_log_panel(StudioContext& ctx);

}  // namespace refocus
