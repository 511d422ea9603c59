// The depth model's sampling and its files; the fit that makes one is in depth_fit.cpp. See
// depth.h.
#include "edit/depth.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

#include "io/image_file.h"
#include "util/error.h"

namespace refocus {

namespace {

using nlohmann::json;

// Bilinear sample of a 1-channel atlas at (u, v) ∈ [−1, 1]² (render/preview.h convention).
inline float sample1(const Image& atlas, float u, float v) {
    int x0, x1, y0, y1;
    float fx, fy;
    preview_atlas_coord(u, atlas.width, x0, x1, fx);
    preview_atlas_coord(v, atlas.height, y0, y1, fy);
    const float top = atlas.at(x0, y0, 0) * (1 - fx) + atlas.at(x1, y0, 0) * fx;
    const float bot = atlas.at(x0, y1, 0) * (1 - fx) + atlas.at(x1, y1, 0) * fx;
    return top * (1 - fy) + bot * fy;
}
}  // namespace

// ---------------------------------------------------------------- sampling

namespace {
int clamp_frame(int t, int frames) {
    return std::clamp(t, 0, std::max(frames - 1, 0));
}

void check_uv(const Image& uv, const char* what) {
    if (uv.channels != 2)
        throw Error(std::string("depth: the ") + what + " UV map needs 2 channels");
}
}  // namespace

PreviewDepth DepthModel::frame_depth(int t, const Image& uv_bg, const Image& uv_fg) const {
    check_uv(uv_bg, "background");
    PreviewDepth out;
    auto sample = [&](const Image& atlas, const Image& uv, float add) {
        Image img(uv.width, uv.height, 1);
        for (int y = 0; y < uv.height; ++y)
            for (int x = 0; x < uv.width; ++x)
                img.at(x, y, 0) = sample1(atlas, uv.at(x, y, 0), uv.at(x, y, 1)) + add;
        return img;
    };
    out.background = sample(bg_atlas, uv_bg, 0.0f);
    if (has_fg() && !uv_fg.empty()) {
        check_uv(uv_fg, "foreground");
        out.foreground =
            sample(fg_atlas, uv_fg, fg_offset.empty() ? 0.0f : fg_offset[clamp_frame(t, frames())]);
    }
    return out;
}

float DepthModel::depth_at_atlas(int layer, float u, float v, int t) const {
    if (layer == Foreground && has_fg())
        return sample1(fg_atlas, u, v) +
               (fg_offset.empty() ? 0.0f : fg_offset[clamp_frame(t, frames())]);
    return sample1(bg_atlas, u, v);
}

float DepthModel::depth_at_pixel(int t, int x, int y, const Image& uv_bg, const Image& uv_fg,
                                 const Image& alpha) const {
    check_uv(uv_bg, "background");
    x = std::clamp(x, 0, uv_bg.width - 1);
    y = std::clamp(y, 0, uv_bg.height - 1);
    if (has_fg() && !alpha.empty() && !uv_fg.empty() && alpha.at(x, y, 0) > 0.5f)
        return depth_at_atlas(Foreground, uv_fg.at(x, y, 0), uv_fg.at(x, y, 1), t);
    return depth_at_atlas(Background, uv_bg.at(x, y, 0), uv_bg.at(x, y, 1), t);
}

Image DepthModel::depth_map(int t, const Image& uv_bg, const Image& uv_fg,
                            const Image& alpha) const {
    check_uv(uv_bg, "background");
    Image out(uv_bg.width, uv_bg.height, 1);
    for (int y = 0; y < out.height; ++y)
        for (int x = 0; x < out.width; ++x)
            out.at(x, y, 0) = depth_at_pixel(t, x, y, uv_bg, uv_fg, alpha);
    return out;
}

// ---------------------------------------------------------------- files

namespace {
const char* kJson = "depth.json";
const char* kBg = "depth_bg.exr";
const char* kFg = "depth_fg.exr";
}  // namespace

bool DepthModel::exists(const fs::path& dir) {
    return fs::exists(dir / kJson);
}

void DepthModel::save(const fs::path& dir) const {
    if (bg_atlas.empty() || bg_atlas.channels != 1 || focus.empty() ||
        fg_offset.size() != focus.size())
        throw Error(
            file_error((dir / kJson).string(), "refusing to save an incomplete depth model"));
    std::error_code ec;
    fs::create_directories(dir, ec);
    write_image_file((dir / kBg).string(), bg_atlas, PixelFormat::ExrFloat, false);
    if (has_fg()) write_image_file((dir / kFg).string(), fg_atlas, PixelFormat::ExrFloat, false);
    json j = {
        {"version", kVersion},
        {"frames", frames()},
        {"bg", {{"file", kBg}, {"width", bg_atlas.width}, {"height", bg_atlas.height}}},
        {"fg", nullptr},
        {"focus", focus},
        {"fg_offset", fg_offset},
        {"rms_px", rms_px},
        {"rounds", rounds},
        {"fit_step", fit_step},
        {"units",
         "inverse depth in px of blur radius at the clip's aperture (seed 001 eq. 1.12, A = 1)"}};
    if (has_fg()) j["fg"] = {{"file", kFg}, {"width", fg_atlas.width}, {"height", fg_atlas.height}};
    write_file_atomic(dir / kJson, j.dump(2) + "\n");  // last: the model is complete when it exists
    if (!has_fg()) fs::remove(dir / kFg, ec);
}

DepthModel DepthModel::load(const fs::path& dir) {
    const std::string jpath = (dir / kJson).string();
    if (!fs::exists(jpath)) throw Error(file_error(jpath, "no depth model here (missing file)"));
    json j;
    try {
        j = json::parse(read_text_file(jpath));
    } catch (const json::exception& e) {
        throw Error(file_error(jpath, std::string("not valid JSON: ") + e.what()));
    }
    auto bad = [&](const std::string& what) { throw Error(file_error(jpath, what)); };
    DepthModel m;
    auto floats = [&](const char* key, size_t n) {
        if (!j.contains(key) || !j[key].is_array() || j[key].size() != n)
            bad(std::string("'") + key + "' must be an array of " + std::to_string(n) + " numbers");
        std::vector<float> v;
        for (const json& x : j[key]) {
            if (!x.is_number() || !std::isfinite(x.get<double>()))
                bad(std::string("'") + key + "' holds a non-finite or non-numeric value");
            v.push_back(x.get<float>());
        }
        return v;
    };
    auto atlas = [&](const char* key, const char* file) {
        const json& a = j[key];
        if (!a.is_object() || !a.contains("width") || !a.contains("height") ||
            !a["width"].is_number_integer() || !a["height"].is_number_integer() ||
            a["width"].get<int>() < 1 || a["height"].get<int>() < 1)
            bad(std::string("'") + key + "' must hold a positive integer width and height");
        const std::string path = (dir / file).string();
        Image img = read_image_file(path, false, NonFinitePolicy::Reject).image;
        if (img.channels != 1 || img.width != a["width"].get<int>() ||
            img.height != a["height"].get<int>())
            throw Error(file_error(path, "is " + std::to_string(img.width) + "x" +
                                             std::to_string(img.height) + "x" +
                                             std::to_string(img.channels) + ", " + kJson +
                                             " says " + std::to_string(a["width"].get<int>()) +
                                             "x" + std::to_string(a["height"].get<int>()) + "x1"));
        return img;
    };
    try {
        if (!j.is_object() || !j.contains("version") || !j["version"].is_number_integer())
            bad("'version' is missing");
        const int version = j["version"].get<int>();
        if (version > kVersion || version < 1)
            bad("version " + std::to_string(version) + " (this Refocus reads depth version " +
                std::to_string(kVersion) + ")");
        if (!j.contains("frames") || !j["frames"].is_number_integer() || j["frames"].get<int>() < 1)
            bad("'frames' must be a positive integer");
        const size_t n = j["frames"].get<size_t>();
        m.focus = floats("focus", n);
        m.fg_offset = floats("fg_offset", n);
        if (!j.contains("bg")) bad("'bg' is missing");
        m.bg_atlas = atlas("bg", kBg);
        if (j.contains("fg") && !j["fg"].is_null()) m.fg_atlas = atlas("fg", kFg);
        m.rms_px = j.value("rms_px", 0.0);
        m.rounds = j.value("rounds", 0);
        m.fit_step = j.value("fit_step", int64_t(-1));
    } catch (const json::exception& e) {
        bad(std::string("malformed: ") + e.what());
    }
    return m;
}

}  // namespace refocus
