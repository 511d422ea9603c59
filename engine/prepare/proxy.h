#pragma once
// Preparation on proxies: flow, camera motion, masks and the radius estimate run on frames at
// most `proxy_width` px wide, and their results are scaled up to the clip's size. Their cost
// then stays flat as the frame grows, and their px-tuned thresholds (feature spacing, RANSAC,
// "static" corners, flow consistency) mean at 4K what they mean at 640 px.
//
// Pixel centres sit at integer coordinates at both sizes, so a proxy pixel x_p is the full-size
// point x = s·x_p + (s − 1)/2, s = W / w (per axis): the map S below.
#include <vector>

#include "io/image.h"
#include "prepare/motion.h"

namespace refocus {

struct PrepareResult;

struct ProxySize {
    int width = 0, height = 0;  // the proxy's size (the clip's own when not active)
    double sx = 1, sy = 1;      // full-size px per proxy px along x and y
    bool active() const { return sx != 1 || sy != 1; }
};

// The proxy for a width × height clip: at most `proxy_width` wide with the clip's aspect
// (height rounded, at least 1); the clip's own size when proxy_width is 0 or not smaller.
ProxySize proxy_size(int width, int height, int proxy_width);

// Area average when shrinking, bilinear when growing (half-pixel centres, cv::resize).
Image resize_image(const Image& img, int width, int height);

// H at full size for a homography H_p between proxy frames: S·H_p·S⁻¹.
Homography scale_homography(const Homography& h, double sx, double sy);

// One result at width × height, frame by frame (a long clip's full-size results need not all be
// in memory at once): a flow field with its vectors times the scale; a 0/1 map resized and
// thresholded at ½; a radius map resized and times the scale; the motion's homographies
// conjugated and its corner motion scaled.
Image scale_flow(const Image& flow, int width, int height);
Image scale_binary(const Image& map, int width, int height);
Image scale_radius(const Image& radius, int width, int height);
CameraMotion scale_motion(const CameraMotion& motion, double sx, double sy);

// The preparation `p`, made at a proxy, at width × height: flow vectors and radii times the
// scale, homographies conjugated, masks and consistency resized (consistency thresholded at ½).
// Returns `p` itself when the sizes agree.
PrepareResult scale_prepare(const PrepareResult& p, int width, int height);

}  // namespace refocus
