#pragma once
// Where the atlases lie, shared by the `fast` and `paper` presets: the background atlas covers
// every frame mapped into the reference frame; the foreground atlas is stabilised on the
// subject's track (subject_track). Also the atlas sampling and the sharpest-view fusion that
// both presets start from.
#include <torch/types.h>

#include <functional>

#include <string>
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

// Per-frame subject position from masks [T,1,H,W] and the clip's flow ([T-1,2,H,W] t → t+1,
// validity [T-1,1,H,W]; undefined: none): the median flow over each mask's core, chained, and
// placed where the masks' centroids are on the median. Without flow: the mask centroid, frames
// without a subject keeping the last one seen, smoothed over ±2 frames.
// With `scale`, also the subject's size per frame (largest 1) where it changes by more than 30%
// over the clip (the flow's expansion over the subject, chained; 1 elsewhere and without flow):
// frame pixel p is at (p − c_t)/scale_t in the subject's own coordinates.
struct FitData;
// A tensor's version counter (bumped by every write into it or a view of it); -1 undefined.
int64_t version(const torch::Tensor& t);
void subject_track(const FitData& d, std::vector<double>& cx, std::vector<double>& cy,
                   std::vector<double>* scale = nullptr);
// 3x3 float64: frame px → the subject's coordinates, (p − (cx, cy)) / scale.
torch::Tensor subject_to_track(double cx, double cy, double scale = 1.0);

// Extent of the subject in coordinates stabilised on the track, plus `margin` px.
AtlasBox subject_box(const torch::Tensor& mask, const std::vector<double>& cx,
                     const std::vector<double>& cy, double margin,
                     const std::vector<double>* scale = nullptr);

// Automatic masks cleaned with the subject's track (d.mask replaced; returns a log line):
// a connected part of a frame's mask whose pixels the other frames' masks hold at the same
// place on the subject (moved along the track) less than `min_persistence` of the time is
// dropped (a wall tile a focus change flagged for a few frames); a frame between frames that
// hold the subject whose mask lost most of it takes the nearest such frame's mask moved along
// the track.
std::string clean_subject_masks(FitData& d, double min_persistence = 0.25);

// Bicubic, border padding, align_corners = false. Bilinear resampling at fractional offsets is
// itself a blur that the atlas would have to undo. (The C++ functional options of LibTorch 1.13
// lack kBicubic; the ATen op takes the mode as an integer: 0 bilinear, 1 nearest, 2 bicubic.)
torch::Tensor sample_bicubic(const torch::Tensor& input, const torch::Tensor& grid);

// The fusions' weight (r + ½)^−4 of a radius map: the frames that saw a point sharpest dominate
// it. Taken as the reciprocal of a square squared: LibTorch takes a general power element by
// element (13% of a 1920×1080×240 set-up).
torch::Tensor sharpness_weight(const torch::Tensor& radius);

// The starting atlas of both presets: every frame of src [T,C,H,W] pulled into an atlas of
// height × width through the inverse of to_atlas ([T,3,3], frame pixel → atlas pixel) and
// accumulated with weight [T,1,H,W] (the presets pass (r + ½)^−4, so that each atlas pixel comes
// from the frames that saw it sharpest). Atlas pixels no frame sees get the weighted mean.
// Returns [C,height,width] (not clamped).
torch::Tensor fuse_frames(const torch::Tensor& to_atlas, int64_t height, int64_t width,
                          const torch::Tensor& src, const torch::Tensor& weight);
// The same with each frame's source ([C,H,W]) and weight ([1,H,W]) made on demand: a long clip's
// derived frames (padded, weighted) then need not all exist at once.
// A box of texels: [x0, x0 + w) × [y0, y0 + h); w = 0 is none.
struct TexelBox {
    int64_t x0 = 0, y0 = 0, w = 0, h = 0;
};
torch::Tensor fuse_frames(const torch::Tensor& to_atlas, int64_t height, int64_t width,
                          const std::function<torch::Tensor(int64_t)>& src,
                          const std::function<torch::Tensor(int64_t)>& weight,
                          const std::function<torch::Tensor(int64_t)>& offset = {},
                          const std::function<TexelBox(int64_t)>& window = {},
                          const torch::Tensor& fallback = {}, bool shortcuts = true);
// With `window`, frame t is pulled into its box of the atlas only (a subject's region of a large
// frame: the rest of the atlas would read its weight's floor alone), and atlas pixels no frame
// reached take `fallback` ([C,height,width]; undefined: the weighted mean).
// The box of atlas texels that frame t's pixels in [x0, x1] × [y0, y1] map to through
// to_atlas[t] (a homography: its corners' box), grown by `grow` texels and cut to the atlas.
TexelBox mapped_box(const torch::Tensor& to_atlas, int64_t t, double x0, double y0, double x1,
                    double y1, double grow, int64_t height, int64_t width);
// A frame mapped by a translation of whole pixels (a static camera's background at scale 1) is
// added as it is, without the samplers, which would read its pixel centres exactly; without a
// window, each frame is sampled over its footprint's box only (`shortcuts`; false: the samplers
// over the whole atlas for every frame, the reference).
// `offset(t)` ([2,H,W] atlas px, optional) is added to frame t's mapping at each frame pixel (a
// residual warp): atlas pixels are pulled back through it by fixed-point iteration
// p ← h⁻¹(a − offset(p)), exact for a warp that varies slowly against its own size.

}  // namespace refocus
