#pragma once
// The fit presets the studio offers, in its combo's order; the Fit panel and the script both
// list from here.
#include <string>
#include <vector>

#include "fit/presets.h"

namespace refocus {

inline std::vector<std::string> studio_preset_names() {
    std::vector<std::string> names;
    for (const auto& p : fit_presets()) names.push_back(p.name);
    return names;
}

// The preset's place in studio_preset_names(); -1 for a name it does not hold.
inline int studio_preset_index(const std::string& name) {
    const auto names = studio_preset_names();
    for (size_t i = 0; i < names.size(); ++i)
        if (names[i] == name) return static_cast<int>(i);
    return -1;
}

}  // namespace refocus
