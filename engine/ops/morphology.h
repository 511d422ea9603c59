#pragma once
// Square max and min filters on [N,C,H,W] maps (dilation and erosion of masks), separable: a
// row pass then a column pass, so a window of (2r+1)² px costs 2(2r+1) comparisons a pixel, not
// (2r+1)². A subject's reach is a window of hundreds of px at 1080p. The result equals
// max_pool2d with kernel 2r+1, stride 1 and padding r (outside the map counts as −inf).
#include <torch/types.h>

namespace refocus {

torch::Tensor max_filter(const torch::Tensor& x, int radius);
torch::Tensor min_filter(const torch::Tensor& x, int radius);

// Box mean over (2r+1)² px with the edges replicated, separable in the same way (2(2r+1) adds a
// pixel): equals avg_pool2d of kernel 2r+1, stride 1, over the map padded by replication, to
// float rounding. The focal-stack radius filters 29 cost maps a frame with it.
torch::Tensor box_filter(const torch::Tensor& x, int radius);

}  // namespace refocus
