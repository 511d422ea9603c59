#include "fit/kept_clip.h"

#include <torch/torch.h>

#include <functional>

#include "model/atlas_geometry.h"
#include "model/clip_cache.h"
#include "prepare/prepare.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

// The kept arrays' scalars.
nlohmann::json clip_manifest(const FitData& d) {
    const auto m = d.to_ref.to(torch::kFloat64).contiguous();
    nlohmann::json track = nullptr;
    if (d.has_subject && d.mask.defined() && !d.legacy_subject_track && !d.legacy_track_gaps) {
        // The fast model's subject track (with its scale), which reads every mask and flow.
        std::vector<double> vx, vy, sc;
        subject_track(d, vx, vy, &sc);
        track = {{"x", vx}, {"y", vy}, {"scale", sc}};
    }
    return {
        {"static_camera", d.static_camera},
        {"subject_track", track},
        {"has_subject", d.has_subject},
        {"fixed_focus_share", d.fixed_focus_share},
        {"flow", d.flow_fwd.defined()},
        {"to_ref", std::vector<double>(m.data_ptr<double>(), m.data_ptr<double>() + m.numel())}};
}

}  // namespace

std::string clip_cache_key(const Project& project, const FitSetupOptions& opts) {
    std::string k = "clip-v1/" + std::to_string(project.frames) + "x" +
                    std::to_string(project.width) + "x" + std::to_string(project.height);
    auto stamp = [&](const fs::path& f) {
        std::error_code ec;
        const auto size = fs::file_size(f, ec);
        const auto time = fs::last_write_time(f, ec).time_since_epoch().count();
        k += "/" + f.filename().string() + ":" + std::to_string(size) + ":" + std::to_string(time);
    };
    stamp(project.frame_path(0));
    stamp(project.frame_path(project.frames - 1));
    k += "/" + std::to_string(std::hash<std::string>{}(
                   read_text_file(fs::path(prepare_dir(project)) / "prepare.json")));
    for (const std::string* given : {&opts.coc_path, &opts.mask_path})
        if (!given->empty()) {
            k += "/" + *given;
            stamp(*given);
        }
    return k + "/" + opts.kernel + "/" + std::to_string(opts.proxy_width) +
           opts.settings.key("radius.") + (opts.single_image_coc ? "/single" : "");
}

bool open_kept_clip(FitData& d) {
    const nlohmann::json m = kept_clip_manifest(d);
    if (m.is_null()) return false;
    try {
        const int64_t T = d.frames, H = d.height, W = d.width;
        const bool subject = m.at("has_subject").get<bool>(), flow = m.at("flow").get<bool>();
        const auto to_ref = m.at("to_ref").get<std::vector<double>>();
        if (int64_t(to_ref.size()) != T * 9) return false;
        const std::string& key = d.cache_key;
        auto input = kept_clip_array(d, "input", {T, 3, H, W}, key);
        auto radius = kept_clip_array(d, "radius", {T, H, W}, key);
        torch::Tensor mask, fwd, valid;
        if (subject) mask = kept_clip_array(d, "mask", {T, 1, H, W}, key);
        if (flow && T > 1) {
            fwd = kept_clip_array(d, "flow_fwd", {T - 1, 2, H, W}, key);
            valid = kept_clip_array(d, "flow_valid", {T - 1, 1, H, W}, key);
        }
        FitData::TrackMemo memo{{}, {}, true, false, false};  // the fast model's track
        const nlohmann::json& track = m.at("subject_track");
        if (track.is_object()) {
            memo.vx = track.at("x").get<std::vector<double>>();
            memo.vy = track.at("y").get<std::vector<double>>();
            memo.scale = track.at("scale").get<std::vector<double>>();
            if (memo.vy.size() != memo.vx.size() || memo.scale.size() != memo.vx.size())
                return false;
        }
        if (!input.defined() || !radius.defined() || (subject && !mask.defined()) ||
            (flow && T > 1 && (!fwd.defined() || !valid.defined())))
            return false;
        d.input = input, d.radius = radius, d.mask = mask, d.flow_fwd = fwd, d.flow_valid = valid;
        d.static_camera = m.at("static_camera").get<bool>();
        d.has_subject = subject;
        d.fixed_focus_share = m.at("fixed_focus_share").get<double>();
        d.to_ref = torch::tensor(to_ref, torch::kFloat64).view({T, 3, 3}).clone();
        d.input_finite = d.radius_finite = true;  // keep_clip checked them
        if (memo.vx.size() == size_t(T)) {
            memo.mask = d.mask, memo.flow = d.flow_fwd;
            memo.versions = {version(d.mask), version(d.flow_fwd)};
            d.track_memo.push_back(std::move(memo));
        }
        return true;
    } catch (const std::exception&) {
        return false;  // a damaged manifest: the arrays are made again
    }
}

void keep_clip(FitData& d, PrepareLog& log) {
    if (d.cache_dir.empty()) return;
    try {
        check_finite(d);  // what is kept is known good: the next command need not read it all
        d.input_finite = d.radius_finite = true;
    } catch (const Error&) {
        return;  // the engine says what is wrong
    }
    try {
        keep_clip_array(d, "input", d.input, d.cache_key);
        keep_clip_array(d, "radius", d.radius, d.cache_key);
        if (d.has_subject) keep_clip_array(d, "mask", d.mask, d.cache_key);
        keep_clip_array(d, "flow_fwd", d.flow_fwd, d.cache_key);
        keep_clip_array(d, "flow_valid", d.flow_valid, d.cache_key);
        keep_clip_manifest(d, clip_manifest(d));
    } catch (const std::exception& e) {
        log.info(std::string("clip arrays: not kept for the next command (") + e.what() + ")");
    }
}

}  // namespace refocus
