#include "ops/morphology.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

namespace refocus {

namespace F = torch::nn::functional;

torch::Tensor max_filter(const torch::Tensor& x, int radius) {
    if (radius <= 0) return x;
    const int64_t k = 2 * int64_t(radius) + 1;
    auto rows = F::max_pool2d(
        x, F::MaxPool2dFuncOptions({1, k}).stride(1).padding(std::vector<int64_t>{0, radius}));
    return F::max_pool2d(
        rows, F::MaxPool2dFuncOptions({k, 1}).stride(1).padding(std::vector<int64_t>{radius, 0}));
}

torch::Tensor min_filter(const torch::Tensor& x, int radius) {
    return -max_filter(-x, radius);
}

torch::Tensor box_filter(const torch::Tensor& x, int radius) {
    if (radius <= 0) return x;
    const int64_t k = 2 * int64_t(radius) + 1;
    auto padded =
        F::pad(x, F::PadFuncOptions({radius, radius, radius, radius}).mode(torch::kReplicate));
    auto rows = F::avg_pool2d(padded, F::AvgPool2dFuncOptions({1, k}).stride(1));
    return F::avg_pool2d(rows, F::AvgPool2dFuncOptions({k, 1}).stride(1));
}

}  // namespace refocus
