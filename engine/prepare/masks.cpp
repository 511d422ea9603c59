#include "prepare/masks.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "io/image_file.h"
#include "prepare/detail.h"
#include "util/error.h"
#include "util/fs.h"
#include "util/threads.h"

namespace refocus {

using namespace prep_detail;

namespace {

// Otsu's threshold (between-class variance maximised) over a 256-bin histogram of [0, p99.5].
float otsu_threshold(const std::vector<float>& v) {
    if (v.empty()) return 0;
    std::vector<float> sorted(v);
    auto hi_it = sorted.begin() + size_t(0.995 * (sorted.size() - 1));
    std::nth_element(sorted.begin(), hi_it, sorted.end());
    const float hi = *hi_it;
    if (!(hi > 0)) return 0;
    constexpr int bins = 256;
    std::vector<double> hist(bins, 0.0);
    for (float x : v) hist[std::clamp(int(x / hi * bins), 0, bins - 1)] += 1;
    double total = 0, sum = 0;
    for (int i = 0; i < bins; ++i) total += hist[i], sum += i * hist[i];
    double w0 = 0, s0 = 0, best = -1;
    int best_i = 0;
    for (int i = 0; i < bins - 1; ++i) {
        w0 += hist[i], s0 += i * hist[i];
        const double w1 = total - w0;
        if (w0 <= 0 || w1 <= 0) continue;
        const double m0 = s0 / w0, m1 = (sum - s0) / w1;
        const double between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if (between > best) best = between, best_i = i;
    }
    return (best_i + 1) * hi / bins;
}

cv::Mat disk_element(int r) {
    return cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * r + 1, 2 * r + 1));
}

// A homography between full-resolution frames, as a map between frames resized to (sw, sh):
// S H S^-1 with S the pixel-centre-preserving scale.
cv::Matx33d scaled_homography(const Homography& hm, int w, int h, int sw, int sh) {
    const cv::Matx33d H(hm.m.data());
    const double sx = double(sw) / w, sy = double(sh) / h;
    const cv::Matx33d S(sx, 0, 0.5 * sx - 0.5, 0, sy, 0.5 * sy - 0.5, 0, 0, 1);
    return S * H * S.inv();
}

// frame t → frame s: to_reference[s]^-1 ∘ to_reference[t].
Homography between(const CameraMotion& m, int t, int s) {
    return m.to_reference[s].inverse() * m.to_reference[t];
}

cv::Mat resized(const cv::Mat& m, int w, int h, int interp) {
    if (m.cols == w && m.rows == h) return m.clone();
    cv::Mat r;
    cv::resize(m, r, cv::Size(w, h), 0, 0, interp);
    return r;
}

}  // namespace

std::vector<Image> adjacent_residuals(const ClipFlow& flow, const CameraMotion& motion, int width,
                                      int height) {
    const int n = int(motion.to_reference.size());
    std::vector<Image> out;
    for (int t = 0; t < n; ++t) {
        Image score(width, height, 1, 0.0f);
        struct Dir {
            const Image* flow;
            const Image* valid;
            Image predicted;
        };
        std::vector<Dir> dirs;
        if (t + 1 < n && size_t(t) < flow.fwd.size())  // t → t+1 is the inverse of pair[t]
            dirs.push_back({&flow.fwd[t], &flow.fwd_valid[t],
                            homography_flow(motion.pair[t].inverse(), width, height)});
        if (t > 0 && size_t(t - 1) < flow.bwd.size())  // t → t−1 is pair[t−1]
            dirs.push_back({&flow.bwd[t - 1], &flow.bwd_valid[t - 1],
                            homography_flow(motion.pair[t - 1], width, height)});
        if (dirs.empty()) {
            out.push_back(score);
            continue;
        }
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                float best_valid = INFINITY;
                for (const Dir& d : dirs) {
                    const float du = d.flow->at(x, y, 0) - d.predicted.at(x, y, 0);
                    const float dv = d.flow->at(x, y, 1) - d.predicted.at(x, y, 1);
                    const float r = std::sqrt(du * du + dv * dv);
                    if (d.valid->at(x, y, 0) > 0.5f) best_valid = std::min(best_valid, r);
                }
                // Inconsistent both ways: occluded or unmatched, no evidence of own motion.
                // (Subject interiors lost this way come back through closing + hole filling.)
                score.at(x, y, 0) = std::isfinite(best_valid) ? best_valid : 0.0f;
            }
        out.push_back(std::move(score));
    }
    return out;
}

std::vector<Image> baseline_residuals(const std::vector<Image>& frames, const CameraMotion& motion,
                                      int out_w, int out_h, const MaskOptions& o) {
    const int n = int(frames.size());
    std::vector<Image> out;
    if (n == 0) return out;
    const int w = frames[0].width, h = frames[0].height;
    // At flow_scale, but never below min_flow_width px wide (DIS's patches need the room).
    const int sw =
        std::min(out_w, std::max(o.min_flow_width, int(std::lround(out_w * o.flow_scale))));
    const int sh = std::max(1, int(std::lround(double(out_h) * sw / out_w)));
    const float to_out_px = float(out_w) / sw;
    std::vector<cv::Mat> grey(n);
    for_each_on_threads(n, 0, [&](int t, int) {
        grey[t] = resized(srgb_grey8(frames[t]), sw, sh, cv::INTER_AREA);
    });
    const cv::Mat all(sh, sw, CV_8UC1, cv::Scalar(255));
    out.resize(n);
    // Frames on each core, each with its own estimator (as compute_clip_flow).
    for_each_on_threads(n, 0, [&](int t, int) {
        auto dis = make_dis(o.flow_preset);
        // The largest residual over the baselines where some partner's flow is consistent
        // (a long baseline breaks down on a fast subject, a short one misses a slow one);
        // where none is, the largest inconsistent one.
        cv::Mat score(sh, sw, CV_32FC1, cv::Scalar(0)), fallback(sh, sw, CV_32FC1, cv::Scalar(0));
        cv::Mat any_known(sh, sw, CV_8UC1, cv::Scalar(0));
        for (int k : o.baselines) {
            if (k < 1) continue;
            std::vector<int> partners;
            if (t - k >= 0) partners.push_back(t - k);
            if (t + k < n) partners.push_back(t + k);
            if (partners.empty()) continue;
            // Smallest residual among the partners where the flow is consistent (an occlusion
            // is inconsistent in one direction only); where no partner is, the largest (a
            // subject moving fast or blurred differently breaks the test, the still background
            // rarely).
            cv::Mat best(sh, sw, CV_32FC1, cv::Scalar(INFINITY)),
                worst(sh, sw, CV_32FC1, cv::Scalar(0));
            for (int p : partners) {
                const cv::Matx33d M = scaled_homography(between(motion, t, p), w, h, sw, sh);
                cv::Mat warped, inside, f, b;
                cv::warpPerspective(grey[p], warped, M, cv::Size(sw, sh),
                                    cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REPLICATE);
                cv::warpPerspective(all, inside, M, cv::Size(sw, sh),
                                    cv::INTER_NEAREST | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT,
                                    0);
                dis_calc(*dis, grey[t], warped, f);
                dis_calc(*dis, warped, grey[t], b);
                const Image fi = to_image(f), bi = to_image(b);
                const Image valid = flow_consistency(fi, bi);
                for (int y = 0; y < sh; ++y)
                    for (int x = 0; x < sw; ++x) {
                        if (!inside.at<unsigned char>(y, x)) continue;
                        const float r = std::hypot(fi.at(x, y, 0), fi.at(x, y, 1)) * to_out_px;
                        if (valid.at(x, y, 0) >= 0.5f)
                            best.at<float>(y, x) = std::min(best.at<float>(y, x), r);
                        else
                            worst.at<float>(y, x) = std::max(worst.at<float>(y, x), r);
                    }
            }
            cv::Mat known = best != INFINITY;
            best.setTo(0.0f, ~known);
            score = cv::max(score, best);
            fallback = cv::max(fallback, worst);
            any_known |= known;
        }
        fallback.copyTo(score, ~any_known);
        out[t] = to_image(resized(score, out_w, out_h, cv::INTER_LINEAR));
    });
    return out;
}

std::vector<Image> threshold_masks(const std::vector<Image>& residuals,
                                   const std::vector<Image>& adjacent, const MaskOptions& o,
                                   double px) {
    std::vector<Image> out;
    for (size_t t = 0; t < residuals.size(); ++t) {
        const Image& res = residuals[t];
        const int w = res.width, h = res.height;
        // Above Otsu's threshold, or the adjacent frames' (a fast subject breaks the long
        // baselines' flow; the adjacent frames see it move several px).
        const float thr = std::max(float(o.min_residual_px * px), otsu_threshold(res.pixels));
        cv::Mat bin(h, w, CV_8UC1);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                bin.at<unsigned char>(y, x) = res.at(x, y, 0) > thr ? 255 : 0;
        if (t < adjacent.size()) {
            // Adjacent frames' residual: median + k·1.4826·MAD of the frame, floored.
            const Image& a = adjacent[t];
            std::vector<float> v(a.pixels);
            auto mid = v.begin() + v.size() / 2;
            std::nth_element(v.begin(), mid, v.end());
            const float med = *mid;
            for (float& x : v) x = std::abs(x - med);
            std::nth_element(v.begin(), mid, v.end());
            const float thr_a = std::max(float(o.adjacent_min_px * px),
                                         med + float(o.adjacent_k_mad * 1.4826) * *mid);
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x)
                    if (a.at(x, y, 0) > thr_a) bin.at<unsigned char>(y, x) = 255;
        }
        const int close_px = int(std::lround(o.close_px * px)),
                  open_px = int(std::lround(o.open_px * px));
        if (close_px > 0) cv::morphologyEx(bin, bin, cv::MORPH_CLOSE, disk_element(close_px));
        if (o.fill_holes) {
            // Holes are background regions not connected to the frame border: flood the
            // background from a padded border and add back whatever it did not reach.
            cv::Mat pad;
            cv::copyMakeBorder(bin, pad, 1, 1, 1, 1, cv::BORDER_CONSTANT, 0);
            cv::floodFill(pad, cv::Point(0, 0), 128);
            cv::Mat holes = pad(cv::Rect(1, 1, w, h)) == 0;
            bin.setTo(255, holes);
        }
        if (open_px > 0) cv::morphologyEx(bin, bin, cv::MORPH_OPEN, disk_element(open_px));
        cv::Mat labels, stats, centroids;
        const int nl = cv::connectedComponentsWithStats(bin, labels, stats, centroids, 8, CV_32S);
        const double min_area = o.min_area_frac * w * h;
        Image m(w, h, 1, 0.0f);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const int l = labels.at<int>(y, x);
                if (l > 0 && l < nl && stats.at<int>(l, cv::CC_STAT_AREA) >= min_area)
                    m.at(x, y, 0) = 1.0f;
            }
        out.push_back(std::move(m));
    }
    return out;
}

std::vector<Image> vote_masks(const std::vector<Image>& masks, const CameraMotion& motion,
                              int full_w, int full_h, double tau) {
    const int n = int(masks.size());
    std::vector<Image> out;
    if (n == 0) return out;
    const int w = masks[0].width, h = masks[0].height;
    std::vector<bool> has(n);
    for (int s = 0; s < n; ++s)
        has[s] = std::any_of(masks[s].pixels.begin(), masks[s].pixels.end(),
                             [](float v) { return v >= 0.5f; });
    const cv::Mat ones(h, w, CV_32FC1, cv::Scalar(1));
    for (int t = 0; t < n; ++t) {
        cv::Mat acc(h, w, CV_32FC1, cv::Scalar(0)), wsum(h, w, CV_32FC1, cv::Scalar(0));
        for (int s = 0; s < n; ++s) {
            const float g = std::exp(-std::abs(s - t) / float(tau));
            if (!has[s] || g < 1e-3f) continue;
            const cv::Matx33d M = scaled_homography(between(motion, t, s), full_w, full_h, w, h);
            cv::Mat warped, inside;
            cv::warpPerspective(as_mat(masks[s]), warped, M, cv::Size(w, h),
                                cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT, 0);
            cv::warpPerspective(ones, inside, M, cv::Size(w, h),
                                cv::INTER_NEAREST | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT, 0);
            acc += g * warped;
            wsum += g * inside;
        }
        Image r(w, h, 1, 0.0f);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const float ws = wsum.at<float>(y, x);
                r.at(x, y, 0) = ws > 0 && acc.at<float>(y, x) >= 0.5f * ws ? 1.0f : 0.0f;
            }
        out.push_back(std::move(r));
    }
    return out;
}

std::vector<Image> refine_masks(const std::vector<Image>& frames, const std::vector<Image>& masks,
                                const MaskOptions& o, double px) {
    std::vector<Image> out;
    const int r_in = std::max(1, int(std::lround(o.refine_in_px * px)));
    const int r_out = std::max(1, int(std::lround(o.refine_out_px * px)));
    for (size_t t = 0; t < masks.size(); ++t) {
        const Image& m = masks[t];
        const int w = m.width, h = m.height;
        cv::Mat bin(h, w, CV_8UC1);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                bin.at<unsigned char>(y, x) = m.at(x, y, 0) >= 0.5f ? 255 : 0;
        if (cv::countNonZero(bin) == 0) {
            out.push_back(m);
            continue;
        }
        cv::Mat inner, outer;
        cv::erode(bin, inner, disk_element(r_in));
        cv::dilate(bin, outer, disk_element(r_out));
        // GrabCut only where the labels are uncertain (plus a margin for its colour models).
        const cv::Rect box = cv::boundingRect(outer);
        const int margin = 2 * r_out;
        const cv::Rect roi = (box + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin)) &
                             cv::Rect(0, 0, w, h);
        cv::Mat gc(h, w, CV_8UC1, cv::Scalar(cv::GC_BGD));
        gc.setTo(cv::GC_PR_BGD, outer);
        gc.setTo(cv::GC_PR_FGD, bin);
        gc.setTo(cv::GC_FGD, inner);
        cv::Mat img(roi.height, roi.width, CV_8UC3);
        const Image& f = frames[t];
        for (int y = 0; y < roi.height; ++y)
            for (int x = 0; x < roi.width; ++x)
                for (int c = 0; c < 3; ++c)
                    img.at<cv::Vec3b>(y, x)[2 - c] =
                        linear_to_srgb8(f.at(roi.x + x, roi.y + y, std::min(c, f.channels - 1)));
        cv::Mat gc_roi = gc(roi).clone(), bgd, fgd;
        try {
            cv::grabCut(img, gc_roi, cv::Rect(), bgd, fgd, o.refine_iters, cv::GC_INIT_WITH_MASK);
        } catch (const cv::Exception&) {  // a colour model it cannot fit (a flat frame): keep
            out.push_back(m);
            continue;
        }
        gc_roi.copyTo(gc(roi));
        Image r(w, h, 1, 0.0f);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const int v = gc.at<unsigned char>(y, x);
                r.at(x, y, 0) = (v == cv::GC_FGD || v == cv::GC_PR_FGD) ? 1.0f : 0.0f;
            }
        out.push_back(std::move(r));
    }
    return out;
}

std::vector<Image> automatic_masks(const std::vector<Image>& frames, const ClipFlow* flow,
                                   const CameraMotion& motion, const MaskOptions& o_in,
                                   std::vector<Image>* residuals) {
    const MaskOptions& o = o_in;
    std::vector<Image> out;
    if (frames.empty()) return out;
    const int w = frames[0].width, h = frames[0].height;
    const int ww = std::min(w, o.work_width);
    const int wh = std::max(1, int(std::lround(double(h) * ww / w)));
    const double px = ww / 320.0;  // the options' px are at a 320 px wide frame
    std::vector<Image> small;
    for (const Image& f : frames)
        small.push_back(ww == w ? f : to_image(resized(as_mat(f), ww, wh, cv::INTER_AREA)));
    std::vector<Image> res = baseline_residuals(frames, motion, ww, wh, o);
    std::vector<Image> adjacent;
    if (flow)
        for (Image& a : adjacent_residuals(*flow, motion, w, h))
            adjacent.push_back(ww == w ? a
                                       : to_image(resized(as_mat(a), ww, wh, cv::INTER_LINEAR)));
    // GrabCut (refine_masks) seeds its colour models from OpenCV's global RNG (thread-local, never
    // reseeded): the masks, and everything fitted from them, depended on what the process had
    // drawn before (two test cases run in one process gave another subject layer than either
    // alone). From the RNG's initial state, as a fresh `refocus` process has it here, every clip's
    // masks are the same anywhere.
    cv::theRNG().state = 0xffffffffULL;
    std::vector<Image> m = refine_masks(small, threshold_masks(res, adjacent, o, px), o, px);
    if (o.vote_tau > 0) m = refine_masks(small, vote_masks(m, motion, w, h, o.vote_tau), o, px);
    for (Image& mi : m) {
        Image full = ww == w ? mi : to_image(resized(as_mat(mi), w, h, cv::INTER_LINEAR));
        for (float& v : full.pixels) v = v >= 0.5f ? 1.0f : 0.0f;
        out.push_back(std::move(full));
    }
    if (residuals) *residuals = std::move(res);
    return out;
}

namespace {

bool is_image_file(const fs::path& p) {
    std::string e = p.extension().string();
    std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return std::tolower(c); });
    return e == ".png" || e == ".jpg" || e == ".jpeg" || e == ".tif" || e == ".tiff" || e == ".exr";
}

long trailing_number(const fs::path& p) {
    const std::string stem = p.stem().string();
    size_t end = stem.find_last_of("0123456789");
    if (end == std::string::npos) return -1;
    size_t begin = stem.find_last_not_of("0123456789", end);
    begin = begin == std::string::npos ? 0 : begin + 1;
    return std::stol(stem.substr(begin, std::min<size_t>(end - begin + 1, 15)));
}

// The `frames` files of a per-frame sequence given as a pattern, a folder or one file.
std::vector<std::string> sequence_files(const std::string& path, int frames,
                                        const std::string& what) {
    const std::string n = std::to_string(frames);
    std::vector<std::string> files;
    if (path.find('%') != std::string::npos) {
        int start = 0;
        if (!fs::exists(format_pattern(path, 0))) {
            if (fs::exists(format_pattern(path, 1)))
                start = 1;
            else
                throw Error(file_error(format_pattern(path, 0),
                                       "no such file (first " + what + " of '" + path +
                                           "'; numbering must start at 0 or 1)"));
        }
        for (int i = 0; i < frames; ++i) {
            const std::string f = format_pattern(path, start + i);
            if (!fs::exists(f))
                throw Error(file_error(f, what + " for frame " + std::to_string(i) +
                                              " is missing (the clip has " + n + " frames: one " +
                                              what + " each)"));
            files.push_back(f);
        }
        const std::string extra = format_pattern(path, start + frames);
        if (fs::exists(extra))
            throw Error(file_error(extra, "one " + what + " too many: the clip has " + n +
                                              " frames (" + what + "s of '" + path + "')"));
        return files;
    }
    if (fs::is_directory(path)) {
        std::vector<std::pair<long, std::string>> found;
        for (const auto& e : fs::directory_iterator(path)) {
            if (!e.is_regular_file() || !is_image_file(e.path())) continue;
            if (e.path().filename().string()[0] == '.') continue;
            found.emplace_back(trailing_number(e.path()), e.path().string());
        }
        std::sort(found.begin(), found.end());
        if (int(found.size()) != frames)
            throw Error(file_error(path, "holds " + std::to_string(found.size()) + " " + what +
                                             " image(s) but the clip has " + n + " frames"));
        for (auto& f : found) files.push_back(f.second);
        return files;
    }
    if (!fs::exists(path)) throw Error(file_error(path, "no such file or folder"));
    if (frames != 1)
        throw Error(file_error(path, "is one image but the clip has " + n +
                                         " frames; pass a folder or a pattern such as "
                                         "masks/mask_%04d.png"));
    return {path};
}

Image read_checked(const std::string& f, int i, int width, int height, const std::string& what) {
    ImageReadResult r = read_image_file(
        f, false, NonFinitePolicy::Reject, i,
        what == "mask" ? "a --mask matte holds values in 0..1: fix the file"
                       : "a --coc radius map holds finite radii in px: fix the file, or fit "
                         "without --coc to estimate the radius");
    if (r.image.width != width || r.image.height != height)
        throw Error(file_error(f,
                               what + " size " + std::to_string(r.image.width) + "x" +
                                   std::to_string(r.image.height) + " differs from the clip's " +
                                   std::to_string(width) + "x" + std::to_string(height),
                               i));
    return std::move(r.image);
}

}  // namespace

std::vector<Image> load_masks(const std::string& path, int frames, int width, int height) {
    std::vector<Image> out;
    const auto files = sequence_files(path, frames, "mask");
    for (int i = 0; i < frames; ++i) {
        Image src = read_checked(files[i], i, width, height, "mask");
        Image m(width, height, 1);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                float v;
                if (src.channels == 4)
                    v = src.at(x, y, 3);
                else if (src.channels >= 3)
                    v = (src.at(x, y, 0) + src.at(x, y, 1) + src.at(x, y, 2)) / 3.0f;
                else
                    v = src.at(x, y, 0);
                m.at(x, y, 0) = std::clamp(v, 0.0f, 1.0f);
            }
        out.push_back(std::move(m));
    }
    return out;
}

std::vector<Image> load_coc_maps(const std::string& path, int frames, int width, int height) {
    std::vector<Image> out;
    const auto files = sequence_files(path, frames, "radius map");
    const float max_radius = max_coc_radius(width, height);
    for (int i = 0; i < frames; ++i) {
        Image src = read_checked(files[i], i, width, height, "radius map");
        Image m(width, height, 1);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                const float v = src.at(x, y, 0);
                if (v < 0)
                    throw Error(file_error(files[i],
                                           "negative radius " + std::to_string(v) + " at pixel (" +
                                               std::to_string(x) + ", " + std::to_string(y) +
                                               "); radii are in px, ≥ 0",
                                           i));
                if (v > max_radius)
                    throw Error(file_error(
                        files[i],
                        "radius " + std::to_string(v) + " px at pixel (" + std::to_string(x) +
                            ", " + std::to_string(y) +
                            ") is beyond what a fit can model (at most " +
                            std::to_string(int(max_radius)) +
                            " px here: half the frame's long side, 256 px at most); check the "
                            "map's units (px of this clip's size)",
                        i));
                m.at(x, y, 0) = v;
            }
        out.push_back(std::move(m));
    }
    return out;
}

}  // namespace refocus
