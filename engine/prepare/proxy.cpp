#include "prepare/proxy.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

#include "prepare/detail.h"
#include "prepare/prepare.h"
#include "util/error.h"

namespace refocus {

using prep_detail::as_mat;

ProxySize proxy_size(int width, int height, int proxy_width) {
    if (width <= 0 || height <= 0) throw Error("proxy: the clip has no pixels");
    if (proxy_width < 0) throw Error("proxy: the proxy width must be 0 (off) or positive");
    ProxySize p;
    p.width = width, p.height = height;
    if (proxy_width == 0 || width <= proxy_width) return p;
    p.width = proxy_width;
    p.height = std::max(1, int(std::lround(double(height) * proxy_width / width)));
    p.sx = double(width) / p.width;
    p.sy = double(height) / p.height;
    return p;
}

Image resize_image(const Image& img, int width, int height) {
    if (img.width == width && img.height == height) return img;
    Image out(width, height, img.channels);
    const bool shrink = width < img.width && height < img.height;
    cv::Mat dst = as_mat(out);
    cv::resize(as_mat(img), dst, cv::Size(width, height), 0, 0,
               shrink ? cv::INTER_AREA : cv::INTER_LINEAR);
    return out;
}

Homography scale_homography(const Homography& h, double sx, double sy) {
    Homography s, s_inv;
    s.m = {sx, 0, (sx - 1) / 2, 0, sy, (sy - 1) / 2, 0, 0, 1};
    s_inv.m = {1 / sx, 0, -(sx - 1) / (2 * sx), 0, 1 / sy, -(sy - 1) / (2 * sy), 0, 0, 1};
    Homography out = s * h * s_inv;
    for (double& v : out.m) v /= out.m[8];  // keep the m[8] = 1 normalisation
    return out;
}

Image scale_flow(const Image& f, int width, int height) {
    const double sx = double(width) / f.width, sy = double(height) / f.height;
    Image out = resize_image(f, width, height);
    for (size_t i = 0; i < out.pixels.size(); i += 2) {
        out.pixels[i] = float(out.pixels[i] * sx);
        out.pixels[i + 1] = float(out.pixels[i + 1] * sy);
    }
    return out;
}

Image scale_binary(const Image& m, int width, int height) {
    Image out = resize_image(m, width, height);
    for (float& v : out.pixels) v = v > 0.5f ? 1.0f : 0.0f;
    return out;
}

Image scale_radius(const Image& r, int width, int height) {
    // A radius in px grows with the frame; the estimate's resolution does not (docs/method.md,
    // Preparation).
    const float s = float(std::sqrt(double(width) / r.width * double(height) / r.height));
    Image out = resize_image(r, width, height);
    for (float& v : out.pixels) v = std::max(0.0f, v * s);
    return out;
}

CameraMotion scale_motion(const CameraMotion& motion, double sx, double sy) {
    CameraMotion m = motion;
    for (auto& h : m.to_reference) h = scale_homography(h, sx, sy);
    for (auto& h : m.pair) h = scale_homography(h, sx, sy);
    m.max_displacement_px *= std::max(sx, sy);
    return m;
}

PrepareResult scale_prepare(const PrepareResult& p, int width, int height) {
    if (p.width == width && p.height == height) return p;
    PrepareResult r = p;
    r.width = width, r.height = height;
    for (size_t t = 0; t < p.flow.fwd.size(); ++t) {
        r.flow.fwd[t] = scale_flow(p.flow.fwd[t], width, height);
        r.flow.bwd[t] = scale_flow(p.flow.bwd[t], width, height);
        r.flow.fwd_valid[t] = scale_binary(p.flow.fwd_valid[t], width, height);
        r.flow.bwd_valid[t] = scale_binary(p.flow.bwd_valid[t], width, height);
    }
    r.motion = scale_motion(p.motion, double(width) / p.width, double(height) / p.height);
    for (auto& m : r.masks) m = resize_image(m, width, height);
    for (auto& c : r.coc) c = scale_radius(c, width, height);
    return r;
}

}  // namespace refocus
