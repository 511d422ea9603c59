#include "log_panel.h"

#include <imgui.h>

#include "studio_context.h"

namespace refocus {

void draw_log_panel(StudioContext& ctx) {
    const FitWorker::Status st = ctx.worker->status(true);
    ImGui::Text("longest UI frame: %.1f ms (during a fit: %.1f ms)", ctx.times.longest_frame_ms,
                ctx.times.longest_fit_frame_ms);
    ImGui::Text("last GLSL preview render: %.1f ms", ctx.times.last_preview_ms);
    ImGui::BeginChild("log", ImVec2(0, 0), true);
    for (const auto& l : st.log) ImGui::TextWrapped("%s", l.c_str());
    if (ImGui::GetScrollY() >= ImGui::GetScrollMaxY()) ImGui::SetScrollHereY(1.0f);
    ImGui::EndChild();
}

}  // namespace refocus
