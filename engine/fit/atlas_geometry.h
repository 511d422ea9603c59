#pragma once
// Where the atlases lie, shared by the `fast` and `paper` presets: the background atlas covers
// every frame mapped into the reference frame; the foreground atlas is stabilised on the
// subject's (smoothed) mask centroid.
#include <torch/types.h>

#include <vector>

namespace refocus {

struct AtlasBox {
    double origin_x = 0, origin_y = 0;  // atlas pixel (0,0) in mapped coordinates
    int64_t width = 0, height = 0;
};

// 3x3 float64 translation.
torch::Tensor translation(double tx, double ty);

// Bounding box of frames of H x W mapped by to_ref ([T,3,3] float64, frame → reference), with a
// 2 px margin, bounded to 3x the frame should a homography go wild.
AtlasBox mapped_frames_box(const torch::Tensor& to_ref, int64_t H, int64_t W);

// Per-frame subject centre from masks [T,1,H,W]: the mask centroid, frames without a subject
// keep the last one seen, smoothed over ±2 frames (thresholded masks jitter as blur changes
// their outline, and a jittering mapping flickers).
void subject_track(const torch::Tensor& mask, std::vector<double>& cx, std::vector<double>& cy);

// Extent of the subject in coordinates stabilised on the track, plus `margin` px.
AtlasBox subject_box(const torch::Tensor& mask, const std::vector<double>& cx,
                     const std::vector<double>& cy, double margin);

}  // namespace refocus
