#include "prepare/prepare.h"
#include "prepare/proxy.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <future>
#include <nlohmann/json.hpp>

#include "io/image_file.h"
#include "project/project.h"
#include "util/error.h"
#include "util/fs.h"
#include "util/threads.h"

namespace refocus {

using json = nlohmann::json;

namespace {

// The share of the frame's outer ring (a band of 1/8 of the frame's size) whose consistent flow
// is under 0.5 px, the median over the pairs; `moving` gets per frame 1 where the flow moves
// (or is not consistent), the rest being the still part a static camera would see.
double still_ring_share(const ClipFlow& flow, std::vector<Image>& moving) {
    std::vector<double> shares;
    const int pairs = int(flow.fwd.size());
    moving.clear();
    for (int t = 0; t < pairs; ++t) {
        const Image& f = flow.fwd[t];
        const Image& v = flow.fwd_valid[t];
        const int w = f.width, h = f.height, bx = std::max(1, w / 8), by = std::max(1, h / 8);
        Image m(w, h, 1, 1.0f);
        double still = 0, all = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const size_t p = size_t(y) * w + x;
                const float fx = f.pixels[p * f.channels], fy = f.pixels[p * f.channels + 1];
                const bool ok = v.pixels[p * v.channels] > 0.5f;
                const bool is_still = ok && fx * fx + fy * fy < 0.25f;
                m.pixels[p] = is_still ? 0.0f : 1.0f;
                if (x < bx || x >= w - bx || y < by || y >= h - by) {
                    all += ok;
                    still += is_still;
                }
            }
        shares.push_back(all > 0 ? still / all : 0.0);
        moving.push_back(std::move(m));
    }
    if (shares.empty()) return 0.0;
    moving.push_back(moving.back());  // the last frame: its predecessor's
    std::nth_element(shares.begin(), shares.begin() + shares.size() / 2, shares.end());
    return shares[shares.size() / 2];
}

constexpr int kPrepareVersion = 1;

std::string fmt(const char* f, double a) {
    char buf[64];
    std::snprintf(buf, sizeof buf, f, a);
    return buf;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double mean_of(const Image& m) {
    double s = 0;
    for (float v : m.pixels) s += v;
    return m.pixels.empty() ? 0.0 : s / m.pixels.size();
}

}  // namespace

PrepareResult prepare_clip(const std::vector<Image>& frames, const PrepareOptions& opts,
                           PrepareLog& log) {
    if (frames.empty()) throw Error("prepare: the clip has no frames");
    PrepareResult res;
    res.width = frames[0].width;
    res.height = frames[0].height;
    res.frames = int(frames.size());
    for (size_t t = 0; t < frames.size(); ++t)
        if (frames[t].width != res.width || frames[t].height != res.height || frames[t].empty())
            throw Error("prepare: frame " + std::to_string(t) + " is " +
                        std::to_string(frames[t].width) + "x" + std::to_string(frames[t].height) +
                        ", frame 0 is " + std::to_string(res.width) + "x" +
                        std::to_string(res.height));
    const int n = res.frames, w = res.width, h = res.height;
    const std::string nf = std::to_string(n);

    // 1. Flow. (The steps' shares, for progress, are the sample clip's timings.)
    log.stage("optical flow", 0.0, 0.45);
    auto t0 = std::chrono::steady_clock::now();
    res.flow = compute_clip_flow(frames, opts.flow);
    // The later stages read res.flow only; the future's destructor waits for it on a throw.
    std::future<void> flow_done;
    if (opts.flow_ready)
        flow_done = std::async(std::launch::async, [&] { opts.flow_ready(res.flow); });
    if (n > 1) {
        double valid = 0;
        for (const auto& v : res.flow.fwd_valid) valid += mean_of(v);
        log.info("flow: " + std::to_string(n - 1) + " frame pairs, forward and backward, " +
                 fmt("%.1f", 100.0 * valid / (n - 1)) + "% consistent (" +
                 fmt("%.2f", seconds_since(t0)) + " s)");
    }

    // 2. Camera motion.
    log.stage("camera motion", 0.45, 0.5);
    t0 = std::chrono::steady_clock::now();
    res.motion = estimate_camera_motion(frames, &res.flow, opts.motion, log);
    {
        int nfeat = 0, nflow = 0, nid = 0;
        for (const auto& s : res.motion.pair_source)
            (s == "features" ? nfeat : s == "flow" ? nflow : nid)++;
        log.info("camera motion: homographies to frame " + std::to_string(res.motion.reference) +
                 " (" + std::to_string(nfeat) + " pairs from features, " + std::to_string(nflow) +
                 " from flow, " + std::to_string(nid) + " identity); corners move up to " +
                 fmt("%.2f", res.motion.max_displacement_px) + " px (" +
                 fmt("%.2f", seconds_since(t0)) + " s)");
    }
    // A static camera tested against the still part of the frame: a subject that fills much of
    // it drags the tracks' consensus along (corners "move" by its motion), while the wall at the
    // frame's edge does not move at all.
    if (opts.motion.background_only && n > 1 && !res.motion.is_static) {
        std::vector<Image> moving;
        const double ring = still_ring_share(res.flow, moving);
        if (ring >= opts.motion.still_ring_share) {
            PrepareLog quiet;  // its per-pair fallbacks were said by the first estimate
            CameraMotion bg =
                estimate_camera_motion(frames, &res.flow, opts.motion, quiet, &moving);
            log.info("camera motion: " + fmt("%.0f", 100 * ring) +
                     "% of the frame's edge stands still; from the still part alone the corners "
                     "move up to " +
                     fmt("%.2f", bg.max_displacement_px) + " px" +
                     (bg.is_static ? ": the camera is static, what moves is the subject"
                                   : ": the first estimate stays"));
            if (bg.is_static) res.motion = bg;
        }
    }
    res.decisions.static_camera = res.motion.is_static;
    if (res.motion.is_static)
        log.info("static camera: no learned background warp (corners move < " +
                 fmt("%.2f", opts.motion.static_max_px) + " px)");

    // 3. Masks.
    log.stage("subject masks", 0.5, 0.9);
    t0 = std::chrono::steady_clock::now();
    if (!opts.mask_path.empty()) {
        const int fw = opts.full_width > 0 ? opts.full_width : w;
        const int fh = opts.full_height > 0 ? opts.full_height : h;
        res.masks = load_masks(opts.mask_path, n, fw, fh);
        for (Image& m : res.masks) m = resize_image(m, w, h);
        res.mask_source = opts.mask_path;
    } else {
        res.mask_source = "auto";
        if (n > 1) {
            res.masks = automatic_masks(frames, &res.flow, res.motion, opts.mask);
        } else {
            res.masks.assign(n, Image(w, h, 1, 0.0f));
            log.info("masks: a single frame has no motion to find a subject from");
        }
    }
    double area = 0;
    for (const auto& m : res.masks) area += mean_of(m);
    area /= n;
    res.decisions.has_subject = area >= opts.subject_min_frac;
    if (!res.decisions.has_subject) {
        log.info("no moving subject: one layer (" +
                 std::string(res.mask_source == "auto" ? "automatic" : "given") + " masks cover " +
                 fmt("%.3f", 100.0 * area) + "% of the frames)");
        if (res.mask_source == "auto")
            for (auto& m : res.masks) std::fill(m.pixels.begin(), m.pixels.end(), 0.0f);
    } else {
        log.info("masks (" + std::string(res.mask_source == "auto" ? "automatic" : "given") +
                 "): subject covers " + fmt("%.1f", 100.0 * area) + "% of the frame on average (" +
                 fmt("%.2f", seconds_since(t0)) + " s)");
    }

    // 4. Circle of confusion.
    res.decisions.frame_sharp.assign(n, 0);
    if (opts.estimate_coc) {
        log.stage("circle of confusion", 0.9, 1.0);
        t0 = std::chrono::steady_clock::now();
        for (const auto& f : frames) res.coc.push_back(estimate_coc(f, opts.coc));
        if (opts.temporal_coc && n > 1) res.coc = smooth_coc_temporally(res.coc, res.flow);
        int sharp = 0;
        std::vector<float> all;
        for (int t = 0; t < n; ++t) {
            size_t below = 0;
            for (float v : res.coc[t].pixels) below += v < opts.sharp_radius_px;
            res.decisions.frame_sharp[t] =
                double(below) >= opts.sharp_frame_frac * res.coc[t].pixels.size();
            sharp += res.decisions.frame_sharp[t];
            all.insert(all.end(), res.coc[t].pixels.begin(), res.coc[t].pixels.end());
        }
        std::nth_element(all.begin(), all.begin() + all.size() / 2, all.end());
        log.info("circle of confusion: median radius " + fmt("%.2f", all[all.size() / 2]) +
                 " px (" + fmt("%.2f", seconds_since(t0)) + " s)");
        res.decisions.all_sharp = sharp == n;
        if (res.decisions.all_sharp)
            log.info("frames already sharp: radius < " + fmt("%.2f", opts.sharp_radius_px) +
                     " px almost everywhere in every frame; no deconvolution needed");
        else if (sharp > 0)
            log.info("frames already sharp: " + std::to_string(sharp) + " of " + nf +
                     " (radius < " + fmt("%.2f", opts.sharp_radius_px) + " px almost everywhere)");
    }
    if (flow_done.valid()) flow_done.get();
    res.log = log.lines();
    return res;
}

// ------------------------------------------------------------------------ files

std::string prepare_dir(const Project& project) {
    return (project.dir / "prep").string();
}

bool has_prepare(const Project& project) {
    return fs::exists(fs::path(prepare_dir(project)) / "prepare.json");
}

namespace {

std::string seq(const std::string& dir, const char* name, int t) {
    return (fs::path(dir) / format_pattern(name, t)).string();
}
constexpr const char* kFlowFwd = "flow_fwd_%04d.exr";
constexpr const char* kFlowBwd = "flow_bwd_%04d.exr";
constexpr const char* kMask = "mask_%04d.png";
constexpr const char* kCoc = "coc_%04d.exr";

Image pack_flow(const Image& f, const Image& valid) {
    Image p(f.width, f.height, 3);
    for (int y = 0; y < f.height; ++y)
        for (int x = 0; x < f.width; ++x) {
            p.at(x, y, 0) = f.at(x, y, 0);
            p.at(x, y, 1) = f.at(x, y, 1);
            p.at(x, y, 2) = valid.at(x, y, 0);
        }
    return p;
}

// A preparation of width × height serves the project: its own size, or a proxy's.
bool made_for(const Project& project, int width, int height) {
    if (width == project.width && height == project.height) return true;
    const ProxySize p = proxy_size(project.width, project.height, width);
    return width > 0 && p.width == width && p.height == height;
}

Image read_expect(const std::string& path, int t, int w, int h, int channels) {
    ImageReadResult r = read_image_file(path, false, NonFinitePolicy::Reject, t,
                                        "the preparation cache is damaged: fit with --reprepare");
    if (r.image.width != w || r.image.height != h)
        throw Error(file_error(path,
                               "size " + std::to_string(r.image.width) + "x" +
                                   std::to_string(r.image.height) + " differs from the project's " +
                                   std::to_string(w) + "x" + std::to_string(h),
                               t));
    if (r.image.channels != channels)
        throw Error(file_error(path,
                               "has " + std::to_string(r.image.channels) +
                                   " channel(s), expected " + std::to_string(channels),
                               t));
    return std::move(r.image);
}

}  // namespace

namespace {

// The preparation's folder, checked against the project and emptied of its marker: a new
// preparation replaces the old one, and the marker goes first so that a crash in between leaves
// no half-old, half-new folder that looks complete.
std::string begin_prepare_files(const Project& project, int width, int height, int frames) {
    const std::string dir = prepare_dir(project);
    if (!made_for(project, width, height) || frames != project.frames)
        throw Error(file_error(dir, "preparation is for " + std::to_string(width) + "x" +
                                        std::to_string(height) + ", " + std::to_string(frames) +
                                        " frames; the project is " + std::to_string(project.width) +
                                        "x" + std::to_string(project.height) + ", " +
                                        std::to_string(project.frames) + " frames"));
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw Error(file_error(dir, "cannot create folder: " + ec.message()));
    fs::remove(fs::path(dir) / "prepare.json", ec);
    return dir;
}

void write_flow_pair(const std::string& dir, const ClipFlow& flow, int t) {
    write_image_file(seq(dir, kFlowFwd, t), pack_flow(flow.fwd[t], flow.fwd_valid[t]),
                     PixelFormat::ExrFloat, false);
    write_image_file(seq(dir, kFlowBwd, t), pack_flow(flow.bwd[t], flow.bwd_valid[t]),
                     PixelFormat::ExrFloat, false);
}

}  // namespace

void save_prepare_flow(const Project& project, const ClipFlow& flow, int width, int height) {
    const int frames = int(flow.fwd.size()) + 1;
    const std::string dir = begin_prepare_files(project, width, height, frames);
    for (int t = 0; t + 1 < frames; ++t) write_flow_pair(dir, flow, t);
}

void save_prepare(const Project& project, const PrepareResult& r, bool flow_saved) {
    if (int(r.masks.size()) != r.frames || int(r.motion.to_reference.size()) != r.frames ||
        int(r.flow.fwd.size()) != std::max(0, r.frames - 1) ||
        (!r.coc.empty() && int(r.coc.size()) != r.frames))
        throw Error(file_error(prepare_dir(project),
                               "preparation result is incomplete (per-frame counts differ)"));
    const std::string dir = begin_prepare_files(project, r.width, r.height, r.frames);

    // A frame's files on each core: encoding a file is serial (1920x1080x240: 24 s on one).
    for_each_on_threads(r.frames, 0, [&](int t, int) {
        if (t + 1 < r.frames && !flow_saved) write_flow_pair(dir, r.flow, t);
        write_image_file(seq(dir, kMask, t), r.masks[t], PixelFormat::Png8, false);
        if (!r.coc.empty())
            write_image_file(seq(dir, kCoc, t), r.coc[t], PixelFormat::ExrFloat, false);
    });

    json j;
    j["version"] = kPrepareVersion;
    j["clip"] = {{"width", r.width}, {"height", r.height}, {"frames", r.frames}};
    j["files"] = {{"flow_fwd", kFlowFwd},
                  {"flow_bwd", kFlowBwd},
                  {"mask", kMask},
                  {"coc", r.coc.empty() ? json(nullptr) : json(kCoc)}};
    j["reference"] = r.motion.reference;
    json hs = json::array();
    for (const auto& hm : r.motion.to_reference) hs.push_back(hm.m);
    j["homographies"] = hs;
    json pairs = json::array();
    for (size_t t = 0; t < r.motion.pair.size(); ++t)
        pairs.push_back({{"h", r.motion.pair[t].m},
                         {"source", r.motion.pair_source[t]},
                         {"inliers", r.motion.pair_inliers[t]}});
    j["pairs"] = pairs;
    j["max_displacement_px"] = r.motion.max_displacement_px;
    j["mask_source"] = r.mask_source;
    j["decisions"] = {{"static_camera", r.decisions.static_camera},
                      {"has_subject", r.decisions.has_subject},
                      {"all_sharp", r.decisions.all_sharp},
                      {"frame_sharp", std::vector<int>(r.decisions.frame_sharp.begin(),
                                                       r.decisions.frame_sharp.end())}};
    j["log"] = r.log;
    write_file_atomic(fs::path(dir) / "prepare.json", j.dump(2) + "\n");
}

PrepareResult load_prepare(const Project& project) {
    const std::string dir = prepare_dir(project);
    const std::string jpath = (fs::path(dir) / "prepare.json").string();
    if (!fs::exists(jpath))
        throw Error(file_error(jpath, "no preparation found (prepare the project first)"));
    json j;
    try {
        j = json::parse(read_text_file(jpath));
    } catch (const json::exception& e) {
        throw Error(file_error(jpath, std::string("not valid JSON: ") + e.what()));
    }
    PrepareResult r;
    const int n = project.frames;
    int w = project.width, h = project.height;
    auto field = [&](const char* what) -> std::string {
        return std::string("field '") + what + "'";
    };
    try {
        if (j.at("version").get<int>() != kPrepareVersion)
            throw Error(file_error(jpath, "version " + j.at("version").dump() +
                                              " is not supported (expected " +
                                              std::to_string(kPrepareVersion) + ")"));
        const json& c = j.at("clip");
        r.width = c.at("width").get<int>();
        r.height = c.at("height").get<int>();
        r.frames = c.at("frames").get<int>();
        if (!made_for(project, r.width, r.height) || r.frames != n)
            throw Error(file_error(
                jpath, "made for " + std::to_string(r.width) + "x" + std::to_string(r.height) +
                           ", " + std::to_string(r.frames) + " frames; the project is " +
                           std::to_string(w) + "x" + std::to_string(h) + ", " + std::to_string(n) +
                           " frames (prepare again)"));
        r.motion.reference = j.at("reference").get<int>();
        if (r.motion.reference < 0 || r.motion.reference >= n)
            throw Error(file_error(jpath, field("reference") + " out of range"));
        const json& hs = j.at("homographies");
        if (!hs.is_array() || int(hs.size()) != n)
            throw Error(file_error(jpath, field("homographies") + " must hold " +
                                              std::to_string(n) + " matrices, one per frame"));
        auto matrix = [&](const json& a, const std::string& where) {
            Homography hm;
            if (!a.is_array() || a.size() != 9)
                throw Error(file_error(jpath, where + " is not a list of 9 numbers"));
            for (int i = 0; i < 9; ++i) {
                hm.m[i] = a[i].get<double>();
                if (!std::isfinite(hm.m[i]))
                    throw Error(file_error(jpath, where + " has a non-finite entry"));
            }
            return hm;
        };
        for (int t = 0; t < n; ++t)
            r.motion.to_reference.push_back(
                matrix(hs[t], "homographies[" + std::to_string(t) + "]"));
        const json& pairs = j.at("pairs");
        if (!pairs.is_array() || int(pairs.size()) != std::max(0, n - 1))
            throw Error(file_error(jpath, field("pairs") + " must hold " +
                                              std::to_string(std::max(0, n - 1)) + " entries"));
        for (size_t t = 0; t < pairs.size(); ++t) {
            r.motion.pair.push_back(matrix(pairs[t].at("h"), "pairs[" + std::to_string(t) + "].h"));
            r.motion.pair_source.push_back(pairs[t].at("source").get<std::string>());
            r.motion.pair_inliers.push_back(pairs[t].at("inliers").get<int>());
        }
        r.motion.max_displacement_px = j.at("max_displacement_px").get<double>();
        r.mask_source = j.at("mask_source").get<std::string>();
        const json& d = j.at("decisions");
        r.decisions.static_camera = d.at("static_camera").get<bool>();
        r.motion.is_static = r.decisions.static_camera;
        r.decisions.has_subject = d.at("has_subject").get<bool>();
        r.decisions.all_sharp = d.at("all_sharp").get<bool>();
        for (int v : d.at("frame_sharp").get<std::vector<int>>())
            r.decisions.frame_sharp.push_back(char(v != 0));
        if (int(r.decisions.frame_sharp.size()) != n)
            throw Error(file_error(
                jpath, "decisions.frame_sharp must hold " + std::to_string(n) + " entries"));
        r.log = j.at("log").get<std::vector<std::string>>();
    } catch (const json::exception& e) {
        throw Error(file_error(jpath, std::string("missing or malformed field: ") + e.what()));
    }
    const bool has_coc = !j["files"]["coc"].is_null();
    w = r.width, h = r.height;  // the files' size: the project's or its proxy's

    for (int t = 0; t + 1 < n; ++t) {
        for (int k = 0; k < 2; ++k) {
            const Image p = read_expect(seq(dir, k ? kFlowBwd : kFlowFwd, t), t, w, h, 3);
            Image f(w, h, 2), v(w, h, 1);
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    f.at(x, y, 0) = p.at(x, y, 0);
                    f.at(x, y, 1) = p.at(x, y, 1);
                    v.at(x, y, 0) = p.at(x, y, 2) > 0.5f ? 1.0f : 0.0f;
                }
            (k ? r.flow.bwd : r.flow.fwd).push_back(std::move(f));
            (k ? r.flow.bwd_valid : r.flow.fwd_valid).push_back(std::move(v));
        }
    }
    for (int t = 0; t < n; ++t) {
        r.masks.push_back(read_expect(seq(dir, kMask, t), t, w, h, 1));
        if (has_coc) {
            Image c = read_expect(seq(dir, kCoc, t), t, w, h, 1);
            for (float v : c.pixels)
                if (v < 0) throw Error(file_error(seq(dir, kCoc, t), "negative radius", t));
            r.coc.push_back(std::move(c));
        }
    }
    return r;
}

}  // namespace refocus
