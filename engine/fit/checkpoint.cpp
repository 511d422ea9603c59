// Checkpoints: save, load and the migration of older versions (FitEngine's, fit_engine.h).
#include <torch/optim.h>
#include <torch/serialize.h>
#include <torch/torch.h>

#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <sstream>

#include "fit/fit_engine.h"
#include "util/checksum.h"
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

// The checksum of a tensor's values (its bytes as stored, contiguous, on the CPU).
std::string tensor_checksum(const torch::Tensor& t) {
    const torch::Tensor c = t.detach().cpu().contiguous();
    return checksum_hex(checksum64(c.data_ptr(), c.numel() * c.element_size()));
}

// The checksum of checkpoint.json's own fields ("checksum" left out).
std::string json_checksum(json j) {
    j.erase("checksum");
    const std::string text = j.dump();
    return checksum_hex(checksum64(text.data(), text.size()));
}

// Writes the archive through a sink that never throws inside LibTorch (an exception there, on a
// full disk, reached the archive writer's destructor and aborted the process): the first write
// error is kept, the rest of the archive is dropped, and the caller reports it.
void save_archive(torch::serialize::OutputArchive& ar, const fs::path& tmp, const fs::path& pt) {
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0)
        throw Error(file_error(pt.string(),
                               std::string("cannot write checkpoint: ") + std::strerror(errno)));
    int err = 0;
    ar.save_to([&](const void* data, size_t n) -> size_t {
        const auto* p = static_cast<const char*>(data);
        for (size_t done = 0; done < n && err == 0;) {
            const ssize_t w = ::write(fd, p + done, n - done);
            if (w < 0 && errno == EINTR) continue;
            if (w <= 0)
                err = w < 0 ? errno : ENOSPC;
            else
                done += size_t(w);
        }
        return n;
    });
    if (err == 0 && ::fsync(fd) != 0) err = errno;
    if (::close(fd) != 0 && err == 0) err = errno;
    if (err != 0) {
        ::unlink(tmp.c_str());
        throw Error(file_error(pt.string(), std::string("cannot write checkpoint: ") +
                                                std::strerror(err) +
                                                " (the previous checkpoint is kept)"));
    }
}

}  // namespace

std::string FitEngine::checkpoint_json_checksum(const json& j) {
    return json_checksum(j);
}

std::string FitEngine::checkpoint_problem(const fs::path& dir, int64_t frames) {
    const fs::path jf = dir / "checkpoint.json";
    try {
        json j = read_json_file(jf);
        const bool json_damaged =
            j.is_object() && j.contains("checksum") && j["checksum"] != json_checksum(j);
        migrate_checkpoint(j, jf);
        validate_checkpoint(j, jf, frames);
        if (json_damaged) return jf.string() + ": damaged checkpoint (its checksum does not match)";
        const fs::path pt = dir / j["tensors"].get<std::string>();
        if (!fs::exists(pt)) return pt.string() + ": the checkpoint's tensor file is missing";
        if (j.contains("tensors_checksum") &&
            j["tensors_checksum"] != checksum_hex(file_checksum64(pt)))
            return pt.string() + ": damaged checkpoint tensors (the checksum does not match)";
    } catch (const std::exception& e) {
        return e.what();
    }
    return "";
}

bool FitEngine::has_checkpoint(const fs::path& dir) {
    return fs::exists(dir / "checkpoint.json");
}

void FitEngine::save_checkpoint(const fs::path& dir) {
    fs::create_directories(dir);
    const std::string pt_name = "checkpoint_" + std::to_string(m_step) + ".pt";
    const fs::path pt = dir / pt_name;
    json sums = json::object();  // per model tensor, checked on load
    std::string tensors_sum;     // of the whole archive
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
        for (auto& [name, t] : m_model->state()) sums["model/" + name] = tensor_checksum(t);
        remove_stale_temporaries(dir);  // a killed fit's half-written archive
        const fs::path tmp = temp_sibling(pt);
        save_archive(ar, tmp, pt);
        tensors_sum = checksum_hex(file_checksum64(tmp));
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
              {"tensors", pt_name},
              {"tensors_checksum", tensors_sum},
              {"checksums", sums}};
    j["checksum"] = json_checksum(j);
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
    // The checksum (of checkpoints written since they carry one) is checked after the fields,
    // whose own messages say more.
    const bool json_damaged =
        j.is_object() && j.contains("checksum") && j["checksum"] != json_checksum(j);
    migrate_checkpoint(j, jf);
    validate_checkpoint(j, jf, m_data->frames);
    if (json_damaged)
        throw Error(file_error(jf.string(),
                               "damaged checkpoint: its checksum does not match "
                               "(edited or corrupted); fit again without --resume"));
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
    if (!fs::exists(pt))
        throw Error(file_error(pt.string(),
                               "the checkpoint's tensor file is missing (deleted?); "
                               "fit again without --resume"));
    const bool damaged = j.contains("tensors_checksum") &&
                         j["tensors_checksum"] != checksum_hex(file_checksum64(pt));
    torch::serialize::InputArchive ar;
    try {
        ar.load_from(pt.string());
    } catch (const std::exception& e) {
        throw Error(file_error(pt.string(), std::string("cannot read checkpoint tensors (") +
                                                (damaged ? "damaged" : "truncated or corrupt") +
                                                "); fit again without --resume"));
    }
    if (damaged) {  // name the tensors whose values changed, where the archive still reads
        std::string which;
        if (j.contains("checksums") && j["checksums"].is_object())
            for (const auto& [name, sum] : j["checksums"].items()) {
                torch::Tensor v;
                if (ar.try_read(archive_name(j, name), v) && sum != tensor_checksum(v))
                    which += (which.empty() ? " in " : ", ") + name;
            }
        throw Error(file_error(pt.string(),
                               "damaged checkpoint tensors: the checksum does not "
                               "match" +
                                   which + "; fit again without --resume"));
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
    const double rms = residual_rms(), trust = reported_trust();
    std::lock_guard<std::mutex> l2(m_snap_mutex);
    m_snap.residual_rms = rms;
    m_snap.trust = trust;
    m_snap.step = m_step;
    m_snap.elapsed_s = m_elapsed;
    // A checkpoint without the figures shows 0 for them up to the next step.
    m_snap.loss = j.value("loss", 0.0);
    m_snap.reblur_psnr = j.value("reblur_psnr", 0.0);
    if (j.contains("terms") && j["terms"].is_object()) m_snap.terms = j["terms"].get<LossTerms>();
    m_snap.atlas_version++;
}

}  // namespace refocus
