#include "prepare/motion.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "prepare/detail.h"
#include "util/error.h"

namespace refocus {

using namespace prep_detail;

void Homography::apply(double x, double y, double& ox, double& oy) const {
    const double w = m[6] * x + m[7] * y + m[8];
    ox = (m[0] * x + m[1] * y + m[2]) / w;
    oy = (m[3] * x + m[4] * y + m[5]) / w;
}

namespace {
cv::Matx33d to_matx(const Homography& h) {
    return cv::Matx33d(h.m.data());
}
Homography from_matx(const cv::Matx33d& a) {
    Homography h;
    const double s = std::abs(a(2, 2)) > 1e-15 ? 1.0 / a(2, 2) : 1.0;
    for (int i = 0; i < 9; ++i) h.m[i] = a.val[i] * s;
    return h;
}
}  // namespace

Homography Homography::operator*(const Homography& o) const {
    return from_matx(to_matx(*this) * to_matx(o));
}

Homography Homography::inverse() const {
    const cv::Matx33d a = to_matx(*this);
    if (std::abs(cv::determinant(a)) < 1e-12) throw Error("homography is singular");
    return from_matx(a.inv());
}

double max_corner_displacement(const Homography& h, int width, int height) {
    const double cx[4] = {0, double(width - 1), 0, double(width - 1)};
    const double cy[4] = {0, 0, double(height - 1), double(height - 1)};
    double worst = 0;
    for (int i = 0; i < 4; ++i) {
        double x, y;
        h.apply(cx[i], cy[i], x, y);
        const double d = std::hypot(x - cx[i], y - cy[i]);
        worst = std::isfinite(d) ? std::max(worst, d) : 1e9;
    }
    return worst;
}

Image homography_flow(const Homography& h, int width, int height) {
    Image f(width, height, 2);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            double ox, oy;
            h.apply(x, y, ox, oy);
            f.at(x, y, 0) = float(ox - x);
            f.at(x, y, 1) = float(oy - y);
        }
    return f;
}

namespace {

// A plausible frame-to-frame camera motion: orientation kept, no wild perspective or scale.
bool plausible(const cv::Mat& H, int w, int h) {
    if (H.empty()) return false;
    cv::Matx33d a(H);
    if (cv::determinant(a) <= 0) return false;
    Homography hh = from_matx(a);
    return max_corner_displacement(hh, w, h) < 0.5 * std::max(w, h);
}

cv::Mat affine_to_homography(const cv::Mat& A) {  // 2x3 → 3x3 (CV_64F)
    cv::Mat H = cv::Mat::eye(3, 3, CV_64F);
    A.copyTo(H(cv::Rect(0, 0, 3, 2)));
    return H;
}

// Mean reprojection distance of src under H against dst (px).
double mean_residual(const cv::Mat& H, const std::vector<cv::Point2f>& src,
                     const std::vector<cv::Point2f>& dst) {
    const cv::Matx33d a(H);
    double sum = 0;
    for (size_t i = 0; i < src.size(); ++i) {
        const cv::Vec3d q = a * cv::Vec3d(src[i].x, src[i].y, 1.0);
        sum += std::hypot(q[0] / q[2] - dst[i].x, q[1] / q[2] - dst[i].y);
    }
    return src.empty() ? 0.0 : sum / src.size();
}

// Homography from frame t+1 to frame t from tracked corners; returns inlier count (0 = failed).
// `keep0`/`keep1` (may be empty): 8-bit masks of where frame t / t+1 may hold a track (the
// background); a corner outside keep0, or tracked outside keep1, is not the camera's.
int pair_from_features(const cv::Mat& g0, const cv::Mat& g1, const MotionOptions& o, cv::Mat& H,
                       const cv::Mat& keep0 = {}, const cv::Mat& keep1 = {}) {
    // Corners per cell of a grid, each cell's quality threshold relative to its own best corner:
    // one frame-wide threshold puts nearly every corner on whatever is in focus, and when that is
    // a moving subject in front of a blurred wall, RANSAC's consensus is the subject's motion
    // (the homographies follow the subject, and its own motion reads as zero).
    std::vector<cv::Point2f> p0;
    const int gx = std::max(1, o.feature_grid_x), gy = std::max(1, o.feature_grid_y);
    const int per_cell = std::max(1, o.max_features / (gx * gy));
    for (int cy = 0; cy < gy; ++cy)
        for (int cx = 0; cx < gx; ++cx) {
            const int x0 = cx * g0.cols / gx, x1 = (cx + 1) * g0.cols / gx;
            const int y0 = cy * g0.rows / gy, y1 = (cy + 1) * g0.rows / gy;
            if (x1 - x0 < 8 || y1 - y0 < 8) continue;
            std::vector<cv::Point2f> cell;
            const cv::Rect r(x0, y0, x1 - x0, y1 - y0);
            if (!keep0.empty() && cv::countNonZero(keep0(r)) < 16) continue;
            cv::goodFeaturesToTrack(g0(r), cell, per_cell, o.feature_quality_cell,
                                    o.feature_min_distance,
                                    keep0.empty() ? cv::noArray() : cv::InputArray(keep0(r)));
            for (const auto& p : cell) p0.emplace_back(p.x + x0, p.y + y0);
        }
    if (int(p0.size()) < o.min_inliers) return 0;
    std::vector<cv::Point2f> p1, back;
    std::vector<unsigned char> st1, st2;
    std::vector<float> err;
    const cv::Size win(15, 15);
    const auto crit = cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01);
    cv::calcOpticalFlowPyrLK(g0, g1, p0, p1, st1, err, win, 3, crit);
    cv::calcOpticalFlowPyrLK(g1, g0, p1, back, st2, err, win, 3, crit);
    std::vector<cv::Point2f> src, dst;  // src in t+1, dst in t
    for (size_t i = 0; i < p0.size(); ++i) {
        if (!st1[i] || !st2[i]) continue;
        if (cv::norm(back[i] - p0[i]) > o.track_fb_max_px) continue;
        if (p1[i].x < 0 || p1[i].y < 0 || p1[i].x > g1.cols - 1 || p1[i].y > g1.rows - 1) continue;
        if (!keep1.empty() && !keep1.at<unsigned char>(int(p1[i].y + 0.5f), int(p1[i].x + 0.5f)))
            continue;
        src.push_back(p1[i]);
        dst.push_back(p0[i]);
    }
    if (int(src.size()) < o.min_inliers) return 0;
    // The camera's motion is what the edge of the frame sees. RANSAC's consensus over the whole
    // frame is the motion with the most consistent tracks, and when a subject is sharp and the
    // wall blurred (its tracks noisy as its blur changes) that is the subject's, or a compromise
    // within the threshold, and the chained homographies drift with it. So the consensus is
    // taken among the tracks in the outer ring of grid cells first, then refitted to every track
    // that agrees with it; the whole frame only if the ring has too few. The ring's threshold is
    // tighter (ring_ransac_px) so that a walking subject's tracks that reach the ring stay out
    // of the consensus.
    std::vector<cv::Point2f> rsrc, rdst;
    for (size_t i = 0; i < src.size(); ++i) {
        const int cx = std::clamp(int(dst[i].x * gx / g0.cols), 0, gx - 1);
        const int cy = std::clamp(int(dst[i].y * gy / g0.rows), 0, gy - 1);
        if (cx == 0 || cy == 0 || cx == gx - 1 || cy == gy - 1) {
            rsrc.push_back(src[i]);
            rdst.push_back(dst[i]);
        }
    }
    std::vector<unsigned char> inl;
    if (int(rsrc.size()) >= 2 * o.min_inliers) {
        const double rpx = o.ring_ransac_px;
        // Affine unless the tracks ask for a homography: its two perspective terms, fitted to
        // noisy tracks of a blurred wall bunched in part of the frame, swing the frame's far side
        // by pixels. A wide lens panning fast is a true homography: there it gathers clearly more
        // of the ring's tracks than an affine map does.
        cv::Mat A = cv::estimateAffine2D(rsrc, rdst, inl, cv::RANSAC, rpx, 4000, 0.999);
        const int nr = int(std::count(inl.begin(), inl.end(), 1));
        std::vector<unsigned char> inl_h;
        cv::Mat Hh = cv::findHomography(rsrc, rdst, cv::RANSAC, rpx, inl_h, 4000, 0.999);
        const int nh = int(std::count(inl_h.begin(), inl_h.end(), 1));
        if (!Hh.empty() && nh >= 4 * o.min_inliers && nh > 1.25 * nr &&
            plausible(Hh, g0.cols, g0.rows)) {
            std::vector<cv::Point2f> hsrc, hdst;
            for (size_t i = 0; i < src.size(); ++i)
                if (mean_residual(Hh, {src[i]}, {dst[i]}) < rpx) {
                    hsrc.push_back(src[i]);
                    hdst.push_back(dst[i]);
                }
            cv::Mat Hr = cv::findHomography(hsrc, hdst, 0);
            H = !Hr.empty() && plausible(Hr, g0.cols, g0.rows) ? Hr : Hh;
            return int(hsrc.size());
        }
        if (!A.empty() && nr >= o.min_inliers) {
            // Every track that agrees with the ring's motion, over the whole frame.
            std::vector<cv::Point2f> asrc, adst;
            for (size_t i = 0; i < src.size(); ++i) {
                const cv::Point2d q(A.at<double>(0, 0) * src[i].x + A.at<double>(0, 1) * src[i].y +
                                        A.at<double>(0, 2),
                                    A.at<double>(1, 0) * src[i].x + A.at<double>(1, 1) * src[i].y +
                                        A.at<double>(1, 2));
                if (std::hypot(q.x - dst[i].x, q.y - dst[i].y) < rpx) {
                    asrc.push_back(src[i]);
                    adst.push_back(dst[i]);
                }
            }
            if (int(asrc.size()) >= o.min_inliers) {
                std::vector<unsigned char> keep;
                cv::Mat Ar = cv::estimateAffine2D(asrc, adst, keep, cv::LMEDS);
                if (!Ar.empty()) A = Ar;
            }
            H = affine_to_homography(A);
            if (int(asrc.size()) < o.min_affine_tracks) {
                // Few tracks agree (a wall too blurred to track between frames of different
                // blur): a translation, their median displacement, which so few noisy tracks
                // pin down better than an affine map.
                std::vector<double> dx, dy;
                for (size_t i = 0; i < asrc.size(); ++i) {
                    dx.push_back(adst[i].x - asrc[i].x);
                    dy.push_back(adst[i].y - asrc[i].y);
                }
                std::nth_element(dx.begin(), dx.begin() + dx.size() / 2, dx.end());
                std::nth_element(dy.begin(), dy.begin() + dy.size() / 2, dy.end());
                H = cv::Mat::eye(3, 3, CV_64F);
                H.at<double>(0, 2) = dx[dx.size() / 2];
                H.at<double>(1, 2) = dy[dy.size() / 2];
                return int(asrc.size());
            }
            if (plausible(H, g0.cols, g0.rows)) return std::max<int>(nr, asrc.size());
        }
    }
    H = cv::findHomography(src, dst, cv::RANSAC, o.ransac_px, inl, 4000, 0.999);
    const int n = int(std::count(inl.begin(), inl.end(), 1));
    if (n < o.min_inliers || !plausible(H, g0.cols, g0.rows)) return 0;
    return n;
}

// Same from the consistent backward flow (t+1 → t) sampled on a grid.
int pair_from_flow(const Image& bwd, const Image& bwd_valid, const MotionOptions& o, cv::Mat& H) {
    std::vector<cv::Point2f> src, dst;
    const int step = std::max(2, std::min(bwd.width, bwd.height) / 40);
    for (int y = step / 2; y < bwd.height; y += step)
        for (int x = step / 2; x < bwd.width; x += step) {
            if (bwd_valid.at(x, y, 0) < 0.5f) continue;
            src.emplace_back(float(x), float(y));
            dst.emplace_back(x + bwd.at(x, y, 0), y + bwd.at(x, y, 1));
        }
    if (int(src.size()) < o.min_inliers) return 0;
    std::vector<unsigned char> inl;
    H = cv::findHomography(src, dst, cv::RANSAC, o.ransac_px, inl, 4000, 0.999);
    const int n = int(std::count(inl.begin(), inl.end(), 1));
    if (n < o.min_inliers || !plausible(H, bwd.width, bwd.height)) return 0;
    return n;
}

// Pairs that are a translation because few tracks agreed (see pair_from_features) take the
// translation of the nearest well-tracked pairs, interpolated in time: a camera's motion is
// smooth over a few frames, and a weak pair's tracks are biased by the change of blur.
void smooth_weak_pairs(CameraMotion& cm, const MotionOptions& o, int w, int h) {
    const int m = int(cm.pair.size());
    auto weak = [&](int i) {
        return cm.pair_source[i] == "features" && cm.pair_inliers[i] < o.min_affine_tracks;
    };
    auto centre_shift = [&](int i, double& dx, double& dy) {
        double x, y;
        cm.pair[i].apply(0.5 * (w - 1), 0.5 * (h - 1), x, y);
        dx = x - 0.5 * (w - 1);
        dy = y - 0.5 * (h - 1);
    };
    const int reach = o.weak_pair_reach;
    std::vector<Homography> out = cm.pair;
    for (int i = 0; i < m; ++i) {
        if (!weak(i)) continue;
        int a = -1, b = -1;
        for (int k = i - 1; k >= std::max(0, i - reach); --k)
            if (!weak(k) && cm.pair_source[k] == "features") {
                a = k;
                break;
            }
        for (int k = i + 1; k <= std::min(m - 1, i + reach); ++k)
            if (!weak(k) && cm.pair_source[k] == "features") {
                b = k;
                break;
            }
        if (a < 0 && b < 0) continue;
        double ax = 0, ay = 0, bx = 0, by = 0, tx, ty;
        if (a >= 0) centre_shift(a, ax, ay);
        if (b >= 0) centre_shift(b, bx, by);
        if (a >= 0 && b >= 0) {
            const double f = double(i - a) / (b - a);
            tx = ax + f * (bx - ax);
            ty = ay + f * (by - ay);
        } else {
            tx = a >= 0 ? ax : bx;
            ty = a >= 0 ? ay : by;
        }
        Homography T;
        T.m[2] = tx;
        T.m[5] = ty;
        out[i] = T;
    }
    cm.pair = out;
}

}  // namespace

CameraMotion estimate_camera_motion(const std::vector<Image>& frames, const ClipFlow* flow,
                                    const MotionOptions& opts, PrepareLog& log,
                                    const std::vector<Image>* subject) {
    CameraMotion cm;
    const int n = int(frames.size());
    if (n == 0) return cm;
    if (opts.reference < 0 || opts.reference >= n)
        throw Error("camera motion: reference frame " + std::to_string(opts.reference) +
                    " out of range 0.." + std::to_string(n - 1));
    cm.reference = opts.reference;
    const int w = frames[0].width, h = frames[0].height;
    std::vector<cv::Mat> grey;
    for (const auto& f : frames) grey.push_back(srgb_grey8(f));
    // Where the subject is (grown by its motion's reach), no track is the camera's.
    std::vector<cv::Mat> keep(n);
    if (subject && int(subject->size()) == n) {
        const int grow = std::max(3, std::min(w, h) / 40);
        const cv::Mat k =
            cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * grow + 1, 2 * grow + 1));
        for (int t = 0; t < n; ++t) {
            const Image& m = (*subject)[t];
            if (m.width != w || m.height != h) continue;
            cv::Mat on(h, w, CV_8U);
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x)
                    on.at<unsigned char>(y, x) =
                        m.pixels[(y * w + x) * m.channels] > 0.1f ? 255 : 0;
            cv::dilate(on, on, k);
            keep[t] = 255 - on;
        }
    }

    std::vector<Homography> to0(n);  // frame t → frame 0
    for (int t = 0; t + 1 < n; ++t) {
        cv::Mat H;
        int inliers = pair_from_features(grey[t], grey[t + 1], opts, H, keep[t], keep[t + 1]);
        std::string source = "features";
        if (inliers == 0 && flow && size_t(t) < flow->bwd.size()) {
            inliers = pair_from_flow(flow->bwd[t], flow->bwd_valid[t], opts, H);
            source = "flow";
            log.info("frames " + std::to_string(t) + "-" + std::to_string(t + 1) +
                     ": too few tracked features for a homography; " +
                     (inliers
                          ? "fitted it to the dense flow (" + std::to_string(inliers) + " inliers)"
                          : std::string("flow fit failed too")));
        }
        Homography pair;
        if (inliers == 0) {
            source = "identity";
            log.info("frames " + std::to_string(t) + "-" + std::to_string(t + 1) +
                     ": no camera motion estimate; assuming none (identity)");
        } else {
            pair = from_matx(cv::Matx33d(H));
        }
        cm.pair.push_back(pair);
        cm.pair_source.push_back(source);
        cm.pair_inliers.push_back(inliers);
    }
    smooth_weak_pairs(cm, opts, w, h);
    for (int t = 0; t + 1 < n; ++t) to0[t + 1] = to0[t] * cm.pair[t];  // (t+1 → t) then (t → 0)
    const Homography ref_inv = to0[opts.reference].inverse();
    for (int t = 0; t < n; ++t) {
        cm.to_reference.push_back(ref_inv * to0[t]);
        cm.max_displacement_px =
            std::max(cm.max_displacement_px, max_corner_displacement(cm.to_reference[t], w, h));
    }
    cm.is_static = cm.max_displacement_px < opts.static_max_px;
    return cm;
}

}  // namespace refocus
