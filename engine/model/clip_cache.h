#pragma once
// A long clip's full-size arrays kept between commands. Opening a fitted project (export, the
// studio, fit --resume) otherwise rebuilds every clip-sized array from the preparation: the
// frames read, the flow and the radius scaled up, the masks cleaned, each layer's radius split;
// minutes at 1920×1080×240 (docs/method.md, Opening a fitted project). A clip whose arrays
// stream through file mappings (FitData::mapped_dir) keeps them as named files in the cache
// folder, each beside a sidecar naming the key of the data it was made from; a later command
// maps them read-only where the key matches, and remakes them where it does not.
#include <torch/types.h>

#include <nlohmann/json.hpp>
#include <string>

#include "model/fit_model.h"

namespace refocus {

// A zero-filled array for the cache's `name`, in a file of its own that keep_clip_array
// publishes (FitData::clip_array's `keep`).
torch::Tensor new_kept_array(const FitData& d, const std::string& name, at::IntArrayRef shape);

// Publishes `t` as the cache's `name` made from `key`: the file new_kept_array made for it,
// renamed into place, or else a copy. A command that still maps the name's previous file keeps
// reading that one. Nothing without a cache folder.
void keep_clip_array(const FitData& d, const std::string& name, const torch::Tensor& t,
                     const std::string& key);

// The cache's `name` mapped read-only where it was kept from `key` with `shape`; undefined
// otherwise (absent, another key, damaged).
torch::Tensor kept_clip_array(const FitData& d, const std::string& name, at::IntArrayRef shape,
                              const std::string& key);

// The folder's manifest (the clip's scalars beside its arrays), stored with d.cache_key; read
// back only under the same key (null otherwise).
void keep_clip_manifest(const FitData& d, const nlohmann::json& j);
nlohmann::json kept_clip_manifest(const FitData& d);

}  // namespace refocus
