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

namespace {

// A flow field resized to width × height, its vectors in full-size px.
Image scale_flow(const Image& f, int width, int height, double sx, double sy) {
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

}  // namespace

PrepareResult scale_prepare(const PrepareResult& p, int width, int height) {
    if (p.width == width && p.height == height) return p;
    const double sx = double(width) / p.width, sy = double(height) / p.height;
    PrepareResult r = p;
    r.width = width, r.height = height;
    for (size_t t = 0; t < p.flow.fwd.size(); ++t) {
        r.flow.fwd[t] = scale_flow(p.flow.fwd[t], width, height, sx, sy);
        r.flow.bwd[t] = scale_flow(p.flow.bwd[t], width, height, sx, sy);
        r.flow.fwd_valid[t] = scale_binary(p.flow.fwd_valid[t], width, height);
        r.flow.bwd_valid[t] = scale_binary(p.flow.bwd_valid[t], width, height);
    }
    for (auto& h : r.motion.to_reference) h = scale_homography(h, sx, sy);
    for (auto& h : r.motion.pair) h = scale_homography(h, sx, sy);
    r.motion.max_displacement_px *= std::max(sx, sy);
    for (auto& m : r.masks) m = resize_image(m, width, height);
    // A radius in px grows with the frame; the estimate's resolution does not (docs/method.md,
    // Preparation).
    const float s = float(std::sqrt(sx * sy));
    for (auto& c : r.coc) {
        c = resize_image(c, width, height);
        for (float& v : c.pixels) v = std::max(0.0f, v * s);
    }
    return r;
}

}  // namespace refocus
