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
#include <functional>
#include <random>
#include <sstream>

#include "fit/fit_engine.h"
#include "util/checksum.h"
#include "util/error.h"
#include "util/json_file.h"
#include "util/mapped.h"
#include "util/timing.h"
#include "util/validate.h"

namespace refocus {

namespace {

using nlohmann::json;

constexpr int kCheckpointVersion = 3;

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

// Version 2 held the optimizer's state ("optimizer") and the running residual ("robust_resid")
// in the model's archive; version 3 names their own files ("optimizer", "residual"). A version
// 2 checkpoint has neither field, and its archive is read for them.
void migrate_v2_to_v3(json& j) {
    j["version"] = 3;
}

// One step per older version: kMigrations[v - 1] brings version v to v + 1.
using Migration = void (*)(json&);
const Migration kMigrations[] = {migrate_v1_to_v2, migrate_v2_to_v3};
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

// Whether `v` names a file in the checkpoint's own folder.
bool plain_name(const json& v) {
    if (!v.is_string()) return false;
    const std::string n = v.get<std::string>();
    return !n.empty() && n.find('/') == std::string::npos && n.find("..") == std::string::npos;
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
    if (!j.contains("tensors") || !plain_name(j["tensors"]))
        json_field_error(corrupt, "tensors", "must name a file in the checkpoint's folder");
    for (const char* key : {"optimizer", "residual"})  // version 3's files, when present
        if (j.contains(key) && !plain_name(j[key]))
            json_field_error(corrupt, key, "must name a file in the checkpoint's folder");
    if (j.contains("residual")) {
        const json& sums = j.contains("residual_checksums") ? j["residual_checksums"] : json();
        bool ok = sums.is_array() && sums.size() == size_t(frames);
        for (size_t i = 0; ok && i < sums.size(); ++i) ok = sums[i].is_string();
        if (!ok)
            json_field_error(
                corrupt, "residual_checksums",
                "must hold one checksum for each of the " + std::to_string(frames) + " frames");
    }
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

using Sink = std::function<void(const void*, size_t)>;

// Writes `tmp` (to become `pt`) through `fill`'s sink, which never throws (an exception inside
// LibTorch's archive writer, on a full disk, reached its destructor and aborted the process):
// the first write error is kept, the rest is dropped, and it is reported after `fill` returns.
void write_checkpoint_file(const fs::path& tmp, const fs::path& pt,
                           const std::function<void(const Sink&)>& fill) {
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0)
        throw Error(file_error(pt.string(),
                               std::string("cannot write checkpoint: ") + std::strerror(errno)));
    int err = 0;
    fill([&](const void* data, size_t n) {
        const auto* p = static_cast<const char*>(data);
        for (size_t done = 0; done < n && err == 0;) {
            const ssize_t w = ::write(fd, p + done, n - done);
            if (w < 0 && errno == EINTR) continue;
            if (w <= 0)
                err = w < 0 ? errno : ENOSPC;
            else
                done += size_t(w);
        }
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

void save_archive(torch::serialize::OutputArchive& ar, const fs::path& tmp, const fs::path& pt) {
    write_checkpoint_file(tmp, pt, [&](const Sink& sink) {
        ar.save_to([&](const void* data, size_t n) -> size_t {
            sink(data, n);
            return n;
        });
    });
}

// Writes `t` ([T, ...] float32) frame after frame, raw, into `tmp` (to become `file`), and
// returns each frame's checksum.
json save_frames(const torch::Tensor& t, const fs::path& tmp, const fs::path& file) {
    json sums = json::array();
    write_checkpoint_file(tmp, file, [&](const Sink& sink) {
        for (int64_t s = 0; s < t.size(0); ++s) {
            const torch::Tensor f = t[s].contiguous();
            sink(f.data_ptr(), size_t(f.numel()) * f.element_size());
            sums.push_back(tensor_checksum(f));
        }
    });
    return sums;
}

// Reads the archive `pt`, whose whole-file checksum should be `sum` (none: not checked), saying
// which named tensors changed when it is damaged and still reads (`sums`: name → checksum).
void read_archive(torch::serialize::InputArchive& ar, const fs::path& pt, const std::string& sum,
                  const json& j, const json& sums) {
    if (!fs::exists(pt))
        throw Error(file_error(pt.string(),
                               "the checkpoint's tensor file is missing (deleted?); "
                               "fit again without --resume"));
    const bool damaged = !sum.empty() && sum != checksum_hex(file_checksum64(pt));
    try {
        ar.load_from(pt.string());
    } catch (const std::exception& e) {
        throw Error(file_error(pt.string(), std::string("cannot read checkpoint tensors (") +
                                                (damaged ? "damaged" : "truncated or corrupt") +
                                                "); fit again without --resume"));
    }
    if (damaged) {  // name the tensors whose values changed, where the archive still reads
        std::string which;
        if (sums.is_object())
            for (const auto& [name, s] : sums.items()) {
                torch::Tensor v;
                if (ar.try_read(archive_name(j, name), v) && s != tensor_checksum(v))
                    which += (which.empty() ? " in " : ", ") + name;
            }
        throw Error(file_error(pt.string(),
                               "damaged checkpoint tensors: the checksum does not "
                               "match" +
                                   which + "; fit again without --resume"));
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
        for (const char* key : {"tensors", "optimizer"}) {
            if (!j.contains(key)) continue;
            const fs::path pt = dir / j[key].get<std::string>();
            if (!fs::exists(pt)) return pt.string() + ": the checkpoint's tensor file is missing";
            const std::string sum = std::string(key) + "_checksum";
            if (j.contains(sum) && j[sum] != checksum_hex(file_checksum64(pt)))
                return pt.string() + ": damaged checkpoint tensors (the checksum does not match)";
        }
        if (j.contains("residual")) {
            const fs::path rf = dir / j["residual"].get<std::string>();
            std::error_code ec;
            const auto size = fs::file_size(rf, ec);
            const int64_t H = j.value("height", int64_t(0)), W = j.value("width", int64_t(0));
            if (ec) return rf.string() + ": the checkpoint's residual file is missing";
            if (size != uintmax_t(frames * H * W) * sizeof(float))
                return rf.string() + ": damaged checkpoint residual (" + std::to_string(size) +
                       " bytes, the clip's frames make " +
                       std::to_string(frames * H * W * int64_t(sizeof(float))) + ")";
            const auto r = mapped_file_tensor(rf, {frames, 1, H, W}, false);
            const auto& sums = j["residual_checksums"];
            for (int64_t s = 0; s < frames; ++s)
                if (tensor_checksum(r[s]) != sums[size_t(s)].get<std::string>())
                    return rf.string() + ": damaged checkpoint residual (frame " +
                           std::to_string(s) + ")";
        }
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
    finish_restore();  // a Read opening's optimizer state is read first, so that it is saved
    const std::string stem = "checkpoint_" + std::to_string(m_step);
    const std::string pt_name = stem + ".pt", optim_name = stem + ".optim.pt",
                      resid_name = stem + ".resid";
    json sums = json::object();  // per model tensor, checked on load
    json resid_sums;             // per frame of the running residual
    std::string tensors_sum, optim_sum;
    {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        remove_stale_temporaries(dir);  // a killed fit's half-written files
        auto publish = [&](torch::serialize::OutputArchive& ar, const std::string& name) {
            const fs::path pt = dir / name, tmp = temp_sibling(pt);
            save_archive(ar, tmp, pt);
            const std::string sum = checksum_hex(file_checksum64(tmp));
            commit_temp(tmp, pt);
            return sum;
        };
        torch::serialize::OutputArchive ar;
        for (auto& [name, t] : m_model->state()) ar.write("model/" + name, t.detach());
        for (auto& [name, t] : m_model->state()) sums["model/" + name] = tensor_checksum(t);
        tensors_sum = publish(ar, pt_name);
        if (m_optim) {
            torch::serialize::OutputArchive opt;
            m_optim->save(opt);
            optim_sum = publish(opt, optim_name);
        }
        const fs::path rf = dir / resid_name, tmp = temp_sibling(rf);
        resid_sums = save_frames(m_resid, tmp, rf);
        commit_temp(tmp, rf);
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
              {"checksums", sums},
              {"residual", resid_name},
              {"residual_checksums", resid_sums}};
    if (m_optim) j["optimizer"] = optim_name, j["optimizer_checksum"] = optim_sum;
    j["checksum"] = json_checksum(j);
    write_file_atomic(dir / "checkpoint.json", j.dump(1));
    // checkpoint.json names only this step's files: the others are removed.
    for (const auto& e : fs::directory_iterator(dir)) {
        const std::string n = e.path().filename().string();
        const std::string ext = e.path().extension().string();
        if (n.rfind("checkpoint_", 0) == 0 && (ext == ".pt" || ext == ".resid") && n != pt_name &&
            n != optim_name && n != resid_name) {
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

void FitEngine::load_optimizer_state(const fs::path& file, const std::string& sum) {
    torch::serialize::InputArchive ar;
    read_archive(ar, file, sum, json::object(), json());
    std::lock_guard<std::mutex> lock(m_model_mutex);
    m_optim->load(ar);
}

torch::Tensor FitEngine::residual_frame(int s) const {
    if (!m_resid.defined()) return {};
    if (m_resid_file.empty()) return m_resid[s];
    std::lock_guard<std::mutex> lock(m_resid_check_mutex);
    if (!m_resid_checked[size_t(s)]) {
        if (tensor_checksum(m_resid[s]) != m_resid_sums[size_t(s)])
            throw Error(file_error(m_resid_file.string(),
                                   "damaged checkpoint residual: frame " + std::to_string(s) +
                                       " does not match its checksum; fit again without --resume"));
        m_resid_checked[size_t(s)] = 1;
    }
    return m_resid[s];
}

void FitEngine::load_checkpoint(const fs::path& dir, CheckpointUse use) {
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
    const auto file_of = [&](const char* key) {
        return j.contains(key) ? dir / j[key].get<std::string>() : fs::path();
    };
    const auto sum_of = [&](const char* key) {
        return j.contains(key) ? j[key].get<std::string>() : std::string();
    };
    // Every file is checked to be there before anything is restored.
    const fs::path optim_file = file_of("optimizer"), resid_file = file_of("residual");
    for (const fs::path& f : {optim_file, resid_file})
        if (!f.empty() && !fs::exists(f))
            throw Error(file_error(f.string(),
                                   "the checkpoint's tensor file is missing (deleted?); "
                                   "fit again without --resume"));
    StageClock clock;  // --debug timing
    clock.next("checkpoint: the model's archive");
    torch::serialize::InputArchive ar;
    read_archive(ar, file_of("tensors"), sum_of("tensors_checksum"), j,
                 j.contains("checksums") ? j["checksums"] : json());
    torch::Tensor resid;  // the running residual: its own file, or (version 2) the archive's
    if (!resid_file.empty()) {
        clock.next("checkpoint: the running residual");
        resid = mapped_file_tensor(resid_file, {m_data->frames, 1, m_data->height, m_data->width},
                                   false);
    } else if (ar.try_read("robust_resid", resid) &&
               resid.sizes().equals({m_data->frames, 1, m_data->height, m_data->width})) {
        auto r = m_data->clip_array({m_data->frames, 1, m_data->height, m_data->width});
        r.copy_(resid);  // a long clip's in its file mapping
        resid = r;
    } else {
        resid = torch::Tensor();  // a checkpoint without it: the running residual starts again
    }
    clock.next("checkpoint: the model's tensors");
    {
        std::lock_guard<std::mutex> lock(m_model_mutex);
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
            throw Error(file_error(file_of("tensors").string(), e.what()));
        }
        make_optimizer();  // load_state may have given the model new tensors (a stored geometry)
        {
            std::lock_guard<std::mutex> l(m_unexplained_mutex);
            m_resid = resid;
            m_resid_file = resid_file;
            if (!resid_file.empty()) {
                m_resid_sums = j["residual_checksums"].get<std::vector<std::string>>();
                m_resid_checked.assign(size_t(m_data->frames), 0);
            }
        }
        m_pending_optim.clear();
        if (m_optim && !optim_file.empty()) {  // version 3: its own file, read when needed
            m_pending_optim = optim_file;
            m_pending_optim_sum = sum_of("optimizer_checksum");
        } else if (m_optim) {
            torch::serialize::InputArchive opt;
            ar.read("optimizer", opt);
            m_optim->load(opt);
        }
    }
    clock.next("checkpoint: the figures");
    m_step = j.at("step").get<int64_t>();
    m_elapsed = j.at("elapsed_s").get<double>();
    m_last_ckpt = m_elapsed;
    std::istringstream rng(j.at("rng").get<std::string>());
    rng >> m_rng;
    m_perm = j.at("perm").get<std::vector<int64_t>>();
    m_perm_pos = j.at("perm_pos").get<size_t>();
    if (use == CheckpointUse::Train) {
        clock.next("checkpoint: the optimizer and residual");
        finish_restore();
    }
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
