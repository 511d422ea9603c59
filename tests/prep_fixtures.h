#pragma once
// Scenes and helpers of the preparation suite (test_prepare.cpp): textures, Mondrians, warps and
// pillbox kernels made with OpenCV, as ground truth for flow, camera motion, masks and radius.
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "io/image.h"
#include "util/error.h"

namespace refocus::test::prep {

inline cv::Mat view(Image& img) {
    return cv::Mat(img.height, img.width, CV_32FC(img.channels), img.data());
}

inline Image from_mat(const cv::Mat& m) {
    Image img(m.cols, m.rows, m.channels());
    cv::Mat v = view(img);
    m.copyTo(v);
    return img;
}

// Smooth random RGB texture in linear [0.05, 0.9]: good for dense flow and corners.
inline cv::Mat texture(int w, int h, unsigned seed, double blur = 1.2) {
    cv::Mat n(h, w, CV_32FC3);
    cv::RNG rng(seed);
    rng.fill(n, cv::RNG::UNIFORM, 0.0, 1.0);
    cv::GaussianBlur(n, n, cv::Size(0, 0), blur);
    cv::normalize(n, n, 0.05, 0.9, cv::NORM_MINMAX);
    return n;
}

// Piecewise-constant rectangles (step edges, the ratio estimator's model), grey, linear.
inline cv::Mat mondrian(int w, int h, unsigned seed, int smin = 14, int smax = 34, int per = 150) {
    cv::Mat m(h, w, CV_32FC3, cv::Scalar::all(0.3));
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> px(-10, w), py(-10, h), sz(smin, smax);
    std::uniform_real_distribution<float> lv(0.05f, 0.9f);
    for (int i = 0; i < w * h / per; ++i) {
        const float v = lv(rng);
        cv::rectangle(m, cv::Rect(px(rng), py(rng), sz(rng), sz(rng)), cv::Scalar::all(v),
                      cv::FILLED);
    }
    return m;
}

// frame(p) = src(A p): A maps frame pixels to source pixels.
inline cv::Mat warp(const cv::Mat& src, const cv::Matx33d& A, int w, int h) {
    cv::Mat out;
    cv::warpPerspective(src, out, cv::Mat(A), cv::Size(w, h),
                        cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REFLECT);
    return out;
}

inline cv::Matx33d translate(double x, double y) {
    return {1, 0, x, 0, 1, y, 0, 0, 1};
}
inline cv::Matx33d scale_about(double s, double cx, double cy) {
    return translate(cx, cy) * cv::Matx33d(s, 0, 0, 0, s, 0, 0, 0, 1) * translate(-cx, -cy);
}

// Normalised pillbox of radius r (pixel coverage by 16x16 super-sampling).
inline cv::Mat disk_kernel(double r) {
    const int R = int(std::ceil(r)) + 1;
    cv::Mat k(2 * R + 1, 2 * R + 1, CV_32F, 0.0f);
    for (int y = -R; y <= R; ++y)
        for (int x = -R; x <= R; ++x) {
            int in = 0;
            for (int j = 0; j < 16; ++j)
                for (int i = 0; i < 16; ++i) {
                    const double sx = x - 0.5 + (i + 0.5) / 16, sy = y - 0.5 + (j + 0.5) / 16;
                    in += sx * sx + sy * sy <= r * r;
                }
            k.at<float>(y + R, x + R) = in / 256.0f;
        }
    return k / cv::sum(k)[0];
}

// A textured disc moving over a panned texture; returns frames and true disc masks.
inline void disc_clip(int w, int h, int n, std::vector<Image>& frames,
                      std::vector<cv::Mat>& truth) {
    const cv::Mat bg = texture(260, 180, 31), fg = texture(40, 40, 32, 0.9) * 0.8 + 0.15;
    const double rad = 12;
    for (int t = 0; t < n; ++t) {
        cv::Mat f = warp(bg, translate(50 + 1.5 * t, 40 + 0.5 * t), w, h);
        cv::Mat m(h, w, CV_8UC1, cv::Scalar(0));
        const double cx = 30 + 4.0 * t, cy = 30 + 1.5 * t;  // moves (4, 1.5) px per frame
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                if (std::hypot(x - cx, y - cy) <= rad) {
                    const int u = std::clamp(int(x - cx + 20), 0, 39),
                              v = std::clamp(int(y - cy + 20), 0, 39);
                    f.at<cv::Vec3f>(y, x) = fg.at<cv::Vec3f>(v, u);
                    m.at<unsigned char>(y, x) = 1;
                }
        frames.push_back(from_mat(f));
        truth.push_back(m);
    }
}

inline double median(std::vector<float> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
}

inline std::string error_of(const std::function<void()>& f) {
    try {
        f();
    } catch (const Error& e) {
        return e.what();
    }
    return "";
}

}  // namespace refocus::test::prep
