#pragma once
// The focal stack's absolute floor (stack_coc.h): what the sharpest view of a layer still holds,
// read from the frames' isolated edges (edge_blur.h) or, past what edges measure, from tile
// spectra (spectral_blur.h), as a smooth surface on the layer's canvas. Internal to stack_coc.
#include <torch/types.h>

#include <string>
#include <vector>

#include "model/fit_model.h"
#include "radius/stack_coc.h"

namespace refocus {

// The composite's absolute blur r0 [Hc,Wc] (edge_blur.h). Each frame's isolated edges are
// measured where the frame holds the layer; an edge of absolute radius e at a pixel whose
// relative radius (the stack's) is rel says r0 = sqrt(e² − rel²) there. Only edges seen within
// floor_rel_max of their sharpest view count: for a point seen far out of focus that difference
// of squares is all noise (e = 6 ± 1 against rel = 5 reads r0 = 0-4.8). The readings of all
// frames, placed on the canvas, are binned in cells and made a smooth surface (floor_surface).
// The frames, not the composite: the composite is resampled and blended, which blurs it by
// 0.5-1 px, and the frames hold many times the edges. Below floor_lo r0 reads 0 and ramps to
// r0 at floor_hi (an edge in focus reads 0-0.75 px). Not the luma-guided filter the relative
// radius is spread with: its locally linear model in luma turns sparse readings into a radius
// that follows the texture (docs/method.md, Radius estimation).
// Where the edges' floor reads past floor_max, the blur is read from tile spectra instead
// (spectral_blur.h).
// to_canvas [T,3,3] frame → canvas; region: the layer's [T,1,H,W] mask (undefined: the frame);
// rel: each frame's relative radius [H,W]; own [Hc,Wc]: where the composite is the layer's own.
// `report` gets the line for the log; *spectral whether the tiles' floor was taken.
torch::Tensor absolute_floor(const FitData& d, const torch::Tensor& to_canvas,
                             const torch::Tensor& region, const std::vector<torch::Tensor>& rel,
                             const torch::Tensor& own, const StackCocOptions& o,
                             std::string& report, bool* spectral);

}  // namespace refocus
