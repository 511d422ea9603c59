#pragma once
#include <torch/torch.h>

namespace refocus {

// Σ over channels of (a − b)², [C,H,W] → [1,1,H,W], in one pass.
torch::Tensor squared_difference(const torch::Tensor& a, const torch::Tensor& b);

// The running argmin over the focal stack's windowed costs, one map a radius (in order k = 0, 1,
// …): the least and largest cost, the (first) argmin, and the costs on either side of it for the
// parabola. `add` is one pass over the pixels; `add_reference` the same in tensor ops (the test's).
struct RunningArgmin {
    torch::Tensor cmin, cmax, best, c0, c1, c2, prev;

    void add(const torch::Tensor& ck, int64_t k);
    void add_reference(const torch::Tensor& ck, int64_t k);
};

}  // namespace refocus
