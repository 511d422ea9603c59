#pragma once
// A long clip's FitData from the arrays the last command kept (model/clip_cache.h), and the
// keeping: the key of the data they are made from, the clip's scalars beside them.
#include <nlohmann/json.hpp>
#include <string>

#include "fit/fit_setup.h"
#include "model/fit_model.h"
#include "project/project.h"
#include "prepare/log.h"

namespace refocus {

// What the clip's kept arrays are made from: the frames as ingested, the preparation, the
// settings that shape the radius and the masks, and the given maps.
std::string clip_cache_key(const Project& project, const FitSetupOptions& opts);

// The clip's arrays and scalars as the command that made them kept them (d.cache_dir,
// d.cache_key); false, d untouched, where any is missing or made from other data.
bool open_kept_clip(FitData& d);

// Keeps d's arrays and scalars for the next command (checked finite first); a failure (a full
// disk) is logged and costs the next command the time to make them, nothing else.
void keep_clip(FitData& d, PrepareLog& log);

}  // namespace refocus
