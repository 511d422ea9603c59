#pragma once
// A tooltip on the last item, shown while it is hovered (disabled items too). This Dear ImGui
// (1.86) has no SetItemTooltip.
#include <imgui.h>

namespace refocus {

inline void item_tip(const char* text) {
    if (ImGui::IsItemHovered(ImGuiHoveredFlags_AllowWhenDisabled)) ImGui::SetTooltip("%s", text);
}

}  // namespace refocus
