#include "prepare/flow.h"

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include <algorithm>
#include <cmath>

#include "prepare/detail.h"
#include "util/error.h"
#include "util/threads.h"

namespace refocus {

namespace prep_detail {

Image to_image(const cv::Mat& m) {
    cv::Mat f;
    if (m.depth() != CV_32F)
        m.convertTo(f, CV_32F);
    else
        f = m;
    Image img(f.cols, f.rows, f.channels());
    cv::Mat dst = as_mat(img);
    f.copyTo(dst);
    return img;
}

cv::Mat linear_grey(const Image& img) {
    cv::Mat g(img.height, img.width, CV_32FC1);
    for (int y = 0; y < img.height; ++y) {
        float* row = g.ptr<float>(y);
        for (int x = 0; x < img.width; ++x) {
            if (img.channels >= 3)
                row[x] = 0.2126f * img.at(x, y, 0) + 0.7152f * img.at(x, y, 1) +
                         0.0722f * img.at(x, y, 2);
            else
                row[x] = img.at(x, y, 0);
        }
    }
    return g;
}

cv::Mat srgb_grey8(const Image& img) {
    cv::Mat lin = linear_grey(img);
    cv::Mat g(img.height, img.width, CV_8UC1);
    for (int y = 0; y < img.height; ++y) {
        const float* src = lin.ptr<float>(y);
        unsigned char* dst = g.ptr<unsigned char>(y);
        for (int x = 0; x < img.width; ++x) dst[x] = linear_to_srgb8(src[x]);
    }
    return g;
}

namespace {
template <typename T>
T bilinear(const cv::Mat& m, float x, float y) {
    // A NaN coordinate (a flow vector gone bad) reads the corner, never outside the image.
    x = x >= 0.0f ? std::min(x, float(m.cols - 1)) : 0.0f;
    y = y >= 0.0f ? std::min(y, float(m.rows - 1)) : 0.0f;
    const int x0 = std::min(int(x), m.cols - 2 < 0 ? 0 : m.cols - 2);
    const int y0 = std::min(int(y), m.rows - 2 < 0 ? 0 : m.rows - 2);
    const int x1 = std::min(x0 + 1, m.cols - 1), y1 = std::min(y0 + 1, m.rows - 1);
    const float fx = x - x0, fy = y - y0;
    const T a = m.at<T>(y0, x0), b = m.at<T>(y0, x1), c = m.at<T>(y1, x0), d = m.at<T>(y1, x1);
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy;
}
}  // namespace

float sample1(const cv::Mat& m, float x, float y) {
    return bilinear<float>(m, x, y);
}
cv::Vec2f sample2(const cv::Mat& m, float x, float y) {
    return bilinear<cv::Vec2f>(m, x, y);
}

}  // namespace prep_detail

using namespace prep_detail;

void prep_detail::dis_calc(cv::DISOpticalFlow& dis, const cv::Mat& a, const cv::Mat& b,
                           cv::Mat& flow) {
    constexpr int kMinSide = 32;
    const int short_side = std::min(a.cols, a.rows);
    if (short_side >= kMinSide) {
        dis.calc(a, b, flow);
    } else {
        const double s = double(kMinSide) / short_side;
        const cv::Size big(int(std::lround(a.cols * s)), int(std::lround(a.rows * s)));
        cv::Mat A, B, F;
        cv::resize(a, A, big, 0, 0, cv::INTER_LINEAR);
        cv::resize(b, B, big, 0, 0, cv::INTER_LINEAR);
        dis.calc(A, B, F);
        cv::resize(F, flow, a.size(), 0, 0, cv::INTER_AREA);
        flow *= 1.0 / s;
    }
    cv::patchNaNs(flow, 0.0);
}

cv::Ptr<cv::DISOpticalFlow> prep_detail::make_dis(FlowPreset p) {
    const int preset =
        p == FlowPreset::Fast ? cv::DISOpticalFlow::PRESET_FAST : cv::DISOpticalFlow::PRESET_MEDIUM;
    auto dis = cv::DISOpticalFlow::create(preset);
    if (p == FlowPreset::Fine) {
        // OpenCV has no FINE preset; this is MEDIUM refined down to the finest scale with
        // denser patches (stride 2) and more variational iterations.
        dis->setFinestScale(0);
        dis->setPatchStride(2);
        dis->setGradientDescentIterations(25);
        dis->setVariationalRefinementIterations(10);
        // The default smoothness (alpha 20) wipes out a small subject's motion on small frames
        // (a 28 px square moving 6 px came out at < 1 px); 10 keeps it and still gives
        // sub-0.1 px error on a translated texture (tests/test_prepare.cpp).
        dis->setVariationalRefinementAlpha(10.0f);
    }
    dis->setUseSpatialPropagation(true);
    return dis;
}

namespace {

Image flow_with(cv::DISOpticalFlow& dis, const cv::Mat& a, const cv::Mat& b) {
    cv::Mat flow;
    dis_calc(dis, a, b, flow);
    return to_image(flow);
}

}  // namespace

Image compute_flow(const Image& from, const Image& to, const FlowOptions& opts) {
    if (from.empty() || !from.same_shape(to))
        throw Error("compute_flow: frames are empty or differ in shape");
    auto dis = make_dis(opts.preset);
    return flow_with(*dis, srgb_grey8(from), srgb_grey8(to));
}

Image flow_consistency(const Image& fwd, const Image& bwd, const FlowOptions& opts) {
    if (fwd.channels != 2 || !fwd.same_shape(bwd))
        throw Error("flow_consistency: need two 2-channel flows of one size");
    const cv::Mat b = as_mat(bwd);
    Image valid(fwd.width, fwd.height, 1, 0.0f);
    const float alpha = float(opts.consistency_alpha), beta = float(opts.consistency_beta);
    for (int y = 0; y < fwd.height; ++y)
        for (int x = 0; x < fwd.width; ++x) {
            const float u = fwd.at(x, y, 0), v = fwd.at(x, y, 1);
            const float tx = x + u, ty = y + v;
            if (tx < 0 || ty < 0 || tx > fwd.width - 1 || ty > fwd.height - 1) continue;
            const cv::Vec2f bb = sample2(b, tx, ty);
            const float ex = u + bb[0], ey = v + bb[1];
            const float lhs = ex * ex + ey * ey;
            const float rhs = alpha * (u * u + v * v + bb[0] * bb[0] + bb[1] * bb[1]) + beta;
            valid.at(x, y, 0) = lhs < rhs ? 1.0f : 0.0f;
        }
    return valid;
}

ClipFlow compute_clip_flow(const std::vector<Image>& frames, const FlowOptions& opts) {
    ClipFlow cf;
    if (frames.size() < 2) return cf;
    const int n = int(frames.size());
    std::vector<cv::Mat> grey(n);
    for_each_on_threads(n, 0, [&](int t, int) { grey[t] = srgb_grey8(frames[t]); });
    cf.fwd.resize(n - 1), cf.bwd.resize(n - 1), cf.fwd_valid.resize(n - 1),
        cf.bwd_valid.resize(n - 1);
    // Pairs on each core, each with its own estimator: DIS's own threads leave cores idle in
    // its serial parts (pyramids, the consistency check). A pair's flow does not depend on the
    // thread that made it.
    for_each_on_threads(n - 1, 0, [&](int t, int) {
        auto est = make_dis(opts.preset);
        cf.fwd[t] = flow_with(*est, grey[t], grey[t + 1]);
        cf.bwd[t] = flow_with(*est, grey[t + 1], grey[t]);
        cf.fwd_valid[t] = flow_consistency(cf.fwd[t], cf.bwd[t], opts);
        cf.bwd_valid[t] = flow_consistency(cf.bwd[t], cf.fwd[t], opts);
    });
    return cf;
}

}  // namespace refocus
