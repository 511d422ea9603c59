#include "log_panel.h"

#include <imgui.h>

#include "studio_context.h"

namespace refocus {

void draw_log_panel(StudioContext& ctx) {
    const FitWorker::Status st = ctx.worker->status(true);
    ImGui::Text("longest UI frame: %.1f ms (during a fit, playback or export: %.1f ms)",
                ctx.times.longest_frame_ms, ctx.times.longest_busy_frame_ms);
    if (ctx.renderer && ctx.source) {
        const int mode = view_mode_index(view_modes()[2]);  // refocused
        ImGui::Text("preview: %s, refocused frame %.0f ms", ctx.renderer->backend_name().c_str(),
                    ctx.renderer->last_full_ms(mode));
    }
    ImGui::BeginChild("log", ImVec2(0, 0), true);
    for (const auto& l : st.log) ImGui::TextWrapped("%s", l.c_str());
    if (ImGui::GetScrollY() >= ImGui::GetScrollMaxY()) ImGui::SetScrollHereY(1.0f);
    ImGui::EndChild();
}

}  // namespace refocus
