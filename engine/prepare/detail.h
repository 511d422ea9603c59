#pragma once
// Internal helpers shared by the preparation stage's files (not part of the public API):
// views of refocus::Image as cv::Mat and the grey conversions the classical estimators use.
#include <opencv2/core.hpp>
#include <opencv2/video/tracking.hpp>

#include "io/image.h"
#include "prepare/flow.h"

namespace refocus::prep_detail {

// A cv::Mat header over the image's pixels (no copy; the image must outlive it).
inline cv::Mat as_mat(Image& img) {
    return cv::Mat(img.height, img.width, CV_32FC(img.channels), img.data());
}
inline cv::Mat as_mat(const Image& img) {
    return cv::Mat(img.height, img.width, CV_32FC(img.channels), const_cast<float*>(img.data()));
}
// A deep copy of a float Mat into an Image.
Image to_image(const cv::Mat& m);

// Linear luminance (Rec. 709 weights) of a 1/3/4-channel linear image, CV_32FC1.
// Blur is linear in linear light, so blur estimation works on this.
cv::Mat linear_grey(const Image& img);
// sRGB-encoded 8-bit grey, CV_8UC1: what feature trackers and DIS expect (perceptual contrast,
// roughly uniform noise).
cv::Mat srgb_grey8(const Image& img);

// The DIS flow of a preset (FlowPreset::Fine is tuned in flow.cpp).
cv::Ptr<cv::DISOpticalFlow> make_dis(FlowPreset p);
// dis.calc(a, b, flow) on any size: OpenCV's DIS crashes on frames whose short side is under
// 32 px (its pyramid runs out below the finest scale: 48x12, 120x30, 160x24 seen), so such
// frames are upsampled to 32 px and the flow brought back; NaN vectors become 0.
void dis_calc(cv::DISOpticalFlow& dis, const cv::Mat& a, const cv::Mat& b, cv::Mat& flow);

// Bilinear sample of a CV_32FC1 / CV_32FC2 Mat at (x, y) with edge clamping.
float sample1(const cv::Mat& m, float x, float y);
cv::Vec2f sample2(const cv::Mat& m, float x, float y);

}  // namespace refocus::prep_detail
