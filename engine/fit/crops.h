#pragma once
// The fit's crop step (docs/method.md, Crops): each step renders, reblurs and scores a crop of
// each frame of its batch instead of the whole frame, so that a step's cost follows the crop's
// size, not the frame's. Here: which crops a step takes, and the window arithmetic the fast
// model samples its per-frame grids with.
#include <torch/types.h>

#include <cstdint>
#include <vector>

namespace refocus {

struct Crops {
    int64_t w = 0, h = 0;       // every frame's crop this step, px
    std::vector<int64_t> x, y;  // each frame's crop corner in its frame
    bool whole = true;          // the crops are the whole frames
};

// The crops of one step for `frames` frames of width × height. Each axis longer than `crop_px`
// is cut into n equal tiles (the last ones overlapping by under n px), n = ⌊L / crop_px⌋ or one
// more, drawn per step and axis; each frame takes one tile, drawn uniformly. Every pixel is then
// in a crop equally often and a crop's mean loss weighs each pixel as the whole frame's does
// (in expectation), and the two tilings' seams differ, so no pixel sits on a crop edge always.
// crop_px 0 (or an axis no longer than it) keeps the whole axis. Drawn from a hash of
// (seed, step): the same seed and step give the same crops, also after a resume.
Crops draw_crops(int64_t width, int64_t height, int64_t crop_px, uint64_t seed, int64_t step,
                 size_t frames);

// The crops grown by `margin` px a side, kept within the frame (shifted inward at its edges) and
// no larger than it; every frame's the same size.
Crops grow_crops(const Crops& crops, int64_t width, int64_t height, int64_t margin);

// The windows crops are rendered and blurred over: each crop grown by `margin` px a side, kept
// within `pad` px of the frame (shifted inward at the frame's edges) and no larger than the
// padded frame; every frame's window has the same size. The lens blur layer renormalises a
// source pixel's kernel over the taps inside its image, so a source within one support of the
// window's edge spreads more light than it would in the whole frame: with `margin` twice the
// widest support such sources cannot reach the crop, and its reblur is the whole frame's.
struct Windows {
    int64_t w = 0, h = 0;
    std::vector<int64_t> x0, y0;  // frame pixel of each window's corner (negative: beyond)
};
Windows crop_windows(const Crops& crops, int64_t width, int64_t height, int64_t margin,
                     int64_t pad);

// Homogeneous frame pixel centres (x, y, 1) of windows of h × w px at (x0[b], y0[b]):
// [B,3,h·w] float32, row-major as pixel_grid's.
torch::Tensor window_pixels(const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                            int64_t h, int64_t w);

// What F::interpolate(x, {H, W}, bilinear, align_corners = `corners`) with its edges repeated
// outward holds over each window ([B,C,hi,wi] → [B,C,h,w]), computed at the window's pixels
// only: a per-frame grid (a residual warp, a matte residual) read at a crop costs the crop's
// size, not the frame's.
torch::Tensor upsample_window(const torch::Tensor& x, int64_t H, int64_t W,
                              const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                              int64_t h, int64_t w, bool corners);

}  // namespace refocus
