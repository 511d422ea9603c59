// Checkpoints: save, load and the migration of older versions (FitEngine's, fit_engine.h).
#include <torch/optim.h>
#include <torch/serialize.h>
#include <torch/torch.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdint>
#include <random>
#include <sstream>

#include "fit/fit_engine.h"
#include "util/error.h"
#include "util/json_file.h"
#include "util/validate.h"

namespace refocus {

namespace {

using nlohmann::json;

constexpr int kCheckpointVersion = 2;

const char* kernel_name(const LensBlurParams& p) {
    return p.kernel == BlurKernel::Pillbox ? "pillbox"
           : p.kernel == BlurKernel::Disk  ? "disk"
                                           : "gaussian";
}

// Version 1 left out what had its first meaning when a field was added: no "kernel" is the
// paper's disk, no "subject_track" the masks' centroids, no "atlas_scale" a 1x atlas. The
// perframe preset kept its frames beside the model ("perframe" in the archive, "perframe_done"
// here); version 2 keeps them as the model's state (model/sharp, model/done).
void migrate_v1_to_v2(json& j) {
    if (!j.contains("kernel")) j["kernel"] = "disk";
    if (!j.contains("subject_track")) j["subject_track"] = "centroid";
    if (!j.contains("atlas_scale")) j["atlas_scale"] = 1.0;
    if (j.value("preset", "") == "perframe") {
        j["archive_names"] = {{"model/sharp", "perframe"}};
        j["perframe_done_v1"] = j.value("perframe_done", json::array());
    }
    j.erase("perframe_done");
    j["version"] = 2;
}

// One step per older version: kMigrations[v - 1] brings version v to v + 1.
using Migration = void (*)(json&);
const Migration kMigrations[] = {migrate_v1_to_v2};
static_assert(sizeof kMigrations / sizeof kMigrations[0] == kCheckpointVersion - 1,
              "one migration step per older checkpoint version");

void migrate_checkpoint(json& j, const fs::path& file) {
    if (!j.is_object())
        throw Error(file_error(file.string(), "corrupt checkpoint: not a JSON object"));
    const json& v = j.contains("version") ? j["version"] : json(1);
    if (!v.is_number_integer() || v.get<int64_t>() < 1)
        throw Error(file_error(file.string(), "corrupt checkpoint: 'version' is " + v.dump()));
    if (v.get<int64_t>() > kCheckpointVersion)
        throw Error(file_error(file.string(), "checkpoint from a newer Refocus (version " +
                                                  v.dump() + ", this build reads up to " +
                                                  std::to_string(kCheckpointVersion) + ")"));
    for (int64_t from = v.get<int64_t>(); from < kCheckpointVersion; ++from)
        kMigrations[from - 1](j);
}

// The archive's name for `name` (a migrated checkpoint may hold it under an older name).
std::string archive_name(const json& j, const std::string& name) {
    if (j.contains("archive_names") && j["archive_names"].contains(name))
        return j["archive_names"][name].get<std::string>();
    return name;
}

// The fields load_checkpoint reads, checked before anything is restored: a checkpoint that was
// edited or damaged is refused as corrupt, naming the file and the field, instead of failing
// deep inside (an index out of range in the batch order, an RNG state that does not parse).
void validate_checkpoint(const json& j, const fs::path& file, int64_t frames) {
    const std::string corrupt = file.string() + ": corrupt checkpoint";
    auto field = [&](const std::string& key) { return corrupt + ": field '" + key + "'"; };
    auto number = [&](const std::string& key) {  // NaN (refused below) when missing or not a number
        return j.contains(key) && j[key].is_number() ? j[key].get<double>() : NAN;
    };
    const json& tensors = j.contains("tensors") ? j["tensors"] : json();
    if (!tensors.is_string() || tensors.get<std::string>().empty() ||
        tensors.get<std::string>().find('/') != std::string::npos ||
        tensors.get<std::string>().find("..") != std::string::npos)
        json_field_error(corrupt, "tensors", "must name a file in the checkpoint's folder");
    checked_int(field("step"), number("step"), 0, INT64_MAX / 2);
    checked_range(field("elapsed_s"), number("elapsed_s"), 0, 1e12);
    std::mt19937_64 probe;
    std::istringstream rng(j.contains("rng") && j["rng"].is_string() ? j["rng"].get<std::string>()
                                                                     : "");
    if (!(rng >> probe)) json_field_error(corrupt, "rng", "is not a generator state");
    if (!j.contains("perm") || !j["perm"].is_array() || j["perm"].size() > size_t(frames))
        json_field_error(corrupt, "perm",
                         "must be a list of at most " + std::to_string(frames) + " frame indices");
    for (const json& v : j["perm"])
        checked_int(field("perm") + " entry", v.is_number() ? v.get<double>() : NAN, 0, frames - 1);
    checked_int(field("perm_pos"), number("perm_pos"), 0, int64_t(j["perm"].size()));
    for (const char* key : {"loss", "reblur_psnr"})  // the last step's figures, shown on reopen
        if (j.contains(key) && !j[key].is_number())
            json_field_error(corrupt, key, "must be a number");
    if (j.contains("terms") && j["terms"].is_object())
        for (const auto& [k, v] : j["terms"].items())
            if (!v.is_number()) json_field_error(corrupt, "terms." + k, "must be a number");
}

}  // namespace

bool FitEngine::has_checkpoint(const fs::path& dir) {
    return fs::exists(dir / "checkpoint.json");
}

void FitEngine::save_checkpoint(const fs::path& dir) {
    fs::create_directories(dir);
    const std::string pt_name = "checkpoint_" + std::to_string(m_step) + ".pt";
    const fs::path pt = dir / pt_name;
    {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        torch::serialize::OutputArchive ar;
        for (auto& [name, t] : m_model->state()) ar.write("model/" + name, t.detach());
        ar.write("robust_resid", m_resid);
        if (m_optim) {
            torch::serialize::OutputArchive opt;
            m_optim->save(opt);
            ar.write("optimizer", opt);
        }
        fs::path tmp = temp_sibling(pt);
        try {
            ar.save_to(tmp.string());
        } catch (const std::exception& e) {
            std::error_code ec;
            fs::remove(tmp, ec);
            throw Error(
                file_error(pt.string(), std::string("cannot write checkpoint: ") + e.what()));
        }
        commit_temp(tmp, pt);
    }
    std::ostringstream rng;
    rng << m_rng;
    FitSnapshot last = snapshot();  // the last step's figures, shown again after a reopen
    json j = {{"version", kCheckpointVersion},
              {"loss", last.loss},
              {"reblur_psnr", last.reblur_psnr},
              {"terms", last.terms},
              {"preset", m_opts.preset},
              {"frames", m_data->frames},
              {"height", m_data->height},
              {"width", m_data->width},
              {"two_layers", m_data->has_subject},
              {"subject_track", m_data->legacy_subject_track ? "centroid"
                                : m_data->legacy_track_gaps  ? "flow"
                                                             : "flow-v2"},
              {"kernel", kernel_name(m_data->blur)},
              {"atlas_scale", m_data->atlas_scale},
              {"step", m_step},
              {"elapsed_s", m_elapsed},
              {"seed", m_opts.seed},
              {"rng", rng.str()},
              {"perm", m_perm},
              {"perm_pos", m_perm_pos},
              {"tensors", pt_name}};
    write_file_atomic(dir / "checkpoint.json", j.dump(1));
    // checkpoint.json names only this step's tensor file: the others are removed.
    for (const auto& e : fs::directory_iterator(dir)) {
        const std::string n = e.path().filename().string();
        if (n.rfind("checkpoint_", 0) == 0 && n != pt_name && e.path().extension() == ".pt") {
            std::error_code ec;
            fs::remove(e.path(), ec);
        }
    }
    m_last_ckpt = m_elapsed;
}

bool FitEngine::maybe_checkpoint(const fs::path& dir) {
    if (m_elapsed - m_last_ckpt < m_opts.checkpoint_seconds) return false;
    save_checkpoint(dir);
    return true;
}

void FitEngine::load_checkpoint(const fs::path& dir) {
    const fs::path jf = dir / "checkpoint.json";
    json j = read_json_file(jf);  // depth bounded; errors name the file
    migrate_checkpoint(j, jf);
    validate_checkpoint(j, jf, m_data->frames);
    auto expect = [&](const char* key, const json& want) {
        if (!j.contains(key) || j[key] != want)
            throw Error(file_error(jf.string(), std::string("checkpoint field '") + key + "' is " +
                                                    (j.contains(key) ? j[key].dump() : "missing") +
                                                    ", this fit has " + want.dump()));
    };
    expect("preset", m_opts.preset);
    expect("frames", m_data->frames);
    expect("height", m_data->height);
    expect("width", m_data->width);
    // The radius and the reblur are in the kernel's terms (the project's fit settings say which
    // kernel to set the data up with).
    expect("kernel", kernel_name(m_data->blur));
    const fs::path pt = dir / j.value("tensors", std::string());
    torch::serialize::InputArchive ar;
    try {
        ar.load_from(pt.string());
    } catch (const std::exception& e) {
        throw Error(file_error(pt.string(), "cannot read checkpoint tensors (truncated?)"));
    }
    std::lock_guard<std::mutex> lock(m_model_mutex);
    {
        // A checkpoint's own subject track ("centroid", "flow": FitData::legacy_subject_track)
        // and atlas scale rebuild the model that way, so its atlases and mappings keep their
        // meaning.
        const std::string kind = j.value("subject_track", std::string("centroid"));
        const bool legacy = m_data->has_subject && kind == "centroid";
        const bool legacy_gaps = m_data->has_subject && kind != "flow-v2";
        const double scale = j.value("atlas_scale", 1.0);
        if (!(scale >= 1 && scale <= 4))
            throw Error(file_error(jf.string(), "checkpoint atlas_scale " +
                                                    j["atlas_scale"].dump() + " is out of range"));
        if (legacy != m_data->legacy_subject_track || legacy_gaps != m_data->legacy_track_gaps ||
            scale != m_data->atlas_scale) {
            m_data->atlas_scale = scale;
            m_data->legacy_subject_track = legacy;
            m_data->legacy_track_gaps = legacy_gaps;
            if (legacy_gaps && m_data->mask_as_stored.defined())
                m_data->mask = m_data->mask_as_stored;
            build_model();
        }
        std::map<std::string, torch::Tensor> s;
        for (auto& [name, t] : m_model->state()) {
            torch::Tensor v;
            if (ar.try_read(archive_name(j, "model/" + name), v))
                s[name] = v;  // the model says what it cannot lack
        }
        if (j.contains("perframe_done_v1")) {  // version 1's perframe frames done
            const auto done = j["perframe_done_v1"].get<std::vector<bool>>();
            auto d = torch::zeros({int64_t(done.size())}, torch::kUInt8);
            for (size_t i = 0; i < done.size(); ++i) d[int64_t(i)] = done[i] ? 1 : 0;
            s["done"] = d;
        }
        try {
            m_model->load_state(s);
        } catch (const Error& e) {
            throw Error(file_error(pt.string(), e.what()));
        }
        make_optimizer();     // load_state may have given the model new tensors (a stored geometry)
        torch::Tensor resid;  // a checkpoint without it: the running residual starts again
        if (ar.try_read("robust_resid", resid) && resid.sizes().equals(m_resid.sizes()))
            m_resid.copy_(resid);
        if (m_optim) {
            torch::serialize::InputArchive opt;
            ar.read("optimizer", opt);
            m_optim->load(opt);
        }
    }
    m_step = j.at("step").get<int64_t>();
    m_elapsed = j.at("elapsed_s").get<double>();
    m_last_ckpt = m_elapsed;
    std::istringstream rng(j.at("rng").get<std::string>());
    rng >> m_rng;
    m_perm = j.at("perm").get<std::vector<int64_t>>();
    m_perm_pos = j.at("perm_pos").get<size_t>();
    std::lock_guard<std::mutex> l2(m_snap_mutex);
    m_snap.step = m_step;
    m_snap.elapsed_s = m_elapsed;
    // A checkpoint without the figures shows 0 for them up to the next step.
    m_snap.loss = j.value("loss", 0.0);
    m_snap.reblur_psnr = j.value("reblur_psnr", 0.0);
    if (j.contains("terms") && j["terms"].is_object()) m_snap.terms = j["terms"].get<LossTerms>();
    m_snap.atlas_version++;
}

}  // namespace refocus
