#pragma once
// The fit's presets in one table: the CLI, the studio and its script list from it, and the
// engine builds a preset's model through it. Adding a preset is one row in presets.cpp.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "model/fit_model.h"
#include "fit/settings.h"

namespace refocus {

struct PresetInfo {
    std::string name;
    std::string description;  // one line, for help texts and the studio
    // false: the preset keeps no atlases (nothing to paint, import or take depth from).
    bool has_atlas = true;
    // The preset's model on the data, its options tuned by `settings` (settings.h).
    std::function<std::unique_ptr<FitModel>(const FitData&, const Settings&, uint64_t seed)> make;
};

// Every preset, the default first.
const std::vector<PresetInfo>& fit_presets();
// Throws Error listing the presets when there is none of that name.
const PresetInfo& find_preset(const std::string& name);
// The names joined by `sep`, e.g. "fast|paper|perframe".
std::string preset_names(const std::string& sep = "|");
// The preset's model (torch's generator seeded first); throws listing the presets.
std::unique_ptr<FitModel> make_model(const std::string& preset, const FitData& data, uint64_t seed,
                                     const Settings& settings = {});

}  // namespace refocus
