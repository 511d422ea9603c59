#include "prepare/masks.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "io/image_file.h"
#include "prepare/detail.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

using namespace prep_detail;

std::vector<Image> flow_residuals(const ClipFlow& flow, const CameraMotion& motion, int width,
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

namespace {

float median_of(std::vector<float> v) {
    if (v.empty()) return 0;
    auto mid = v.begin() + v.size() / 2;
    std::nth_element(v.begin(), mid, v.end());
    return *mid;
}

cv::Mat disk_element(int r) {
    return cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * r + 1, 2 * r + 1));
}

}  // namespace

std::vector<Image> auto_masks(const std::vector<Image>& residuals, const MaskOptions& o) {
    std::vector<Image> out;
    for (const Image& res : residuals) {
        const int w = res.width, h = res.height;
        const float med = median_of(res.pixels);
        std::vector<float> dev(res.pixels.size());
        for (size_t i = 0; i < dev.size(); ++i) dev[i] = std::abs(res.pixels[i] - med);
        const float mad = 1.4826f * median_of(dev);
        const float thr = std::max(float(o.min_residual_px), med + float(o.k_mad) * mad);
        cv::Mat bin(h, w, CV_8UC1);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                bin.at<unsigned char>(y, x) = res.at(x, y, 0) > thr ? 255 : 0;
        if (o.close_px > 0) cv::morphologyEx(bin, bin, cv::MORPH_CLOSE, disk_element(o.close_px));
        if (o.fill_holes) {
            // Holes are background regions not connected to the frame border: flood the
            // background from a padded border and add back whatever it did not reach.
            cv::Mat pad;
            cv::copyMakeBorder(bin, pad, 1, 1, 1, 1, cv::BORDER_CONSTANT, 0);
            cv::floodFill(pad, cv::Point(0, 0), 128);
            cv::Mat holes = pad(cv::Rect(1, 1, w, h)) == 0;
            bin.setTo(255, holes);
        }
        if (o.open_px > 0) cv::morphologyEx(bin, bin, cv::MORPH_OPEN, disk_element(o.open_px));
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
    ImageReadResult r = read_image_file(f, false, NonFinitePolicy::Reject, i);
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
                m.at(x, y, 0) = v;
            }
        out.push_back(std::move(m));
    }
    return out;
}

}  // namespace refocus
