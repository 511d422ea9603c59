#include "ops/morphology.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <limits>
#include <vector>

namespace refocus {

namespace F = torch::nn::functional;

namespace {

// Van Herk / Gil-Werman running max along one axis (window k = 2r + 1, −inf outside): the padded
// line cut into blocks of k, a forward max g and a backward max h within each block; the window
// starting at j spans at most two blocks, its max is max(h[j], g[j + k − 1]). Three comparisons
// a sample whatever k. `lines` lines of `n` samples, `step` apart along the line and `lane`
// apart between lines; lanes are walked in the inner loop so the column pass reads whole rows.
void running_max(const float* in, float* out, int64_t lines, int64_t n, int64_t step, int64_t lane,
                 int r) {
    const int64_t k = 2 * int64_t(r) + 1;
    const int64_t L = ((n + 2 * r + k - 1) / k) * k;  // padded length, whole blocks
    constexpr float kNeg = -std::numeric_limits<float>::infinity();
    at::parallel_for(0, lines, 16, [&](int64_t l0, int64_t l1) {
        const int64_t m = l1 - l0;
        std::vector<float> g(size_t(L * m)), h(size_t(L * m));
        auto at = [&](int64_t j, int64_t l) {  // padded sample j of line l0 + l
            const int64_t i = j - r;
            return i < 0 || i >= n ? kNeg : in[i * step + (l0 + l) * lane];
        };
        for (int64_t j = 0; j < L; ++j) {
            float* gj = &g[size_t(j * m)];
            const float* gp = j % k == 0 ? nullptr : &g[size_t((j - 1) * m)];
            for (int64_t l = 0; l < m; ++l) gj[l] = gp ? std::max(gp[l], at(j, l)) : at(j, l);
        }
        for (int64_t j = L - 1; j >= 0; --j) {
            float* hj = &h[size_t(j * m)];
            const float* hn = j % k == k - 1 ? nullptr : &h[size_t((j + 1) * m)];
            for (int64_t l = 0; l < m; ++l) hj[l] = hn ? std::max(hn[l], at(j, l)) : at(j, l);
        }
        for (int64_t i = 0; i < n; ++i) {
            const float* hi = &h[size_t(i * m)];
            const float* gi = &g[size_t((i + k - 1) * m)];
            for (int64_t l = 0; l < m; ++l)
                out[i * step + (l0 + l) * lane] = std::max(hi[l], gi[l]);
        }
    });
}

}  // namespace

torch::Tensor max_filter(const torch::Tensor& x, int radius) {
    if (radius <= 0) return x;
    // Large windows on plain float maps: the running max (its cost does not grow with r). Small
    // ones, other types and anything that needs a gradient: max pooling, the reference.
    if (radius >= 4 && x.dim() == 4 && x.scalar_type() == torch::kFloat32 && x.device().is_cpu() &&
        !x.requires_grad()) {
        const auto src = x.contiguous();
        const int64_t P = src.size(0) * src.size(1), H = src.size(2), W = src.size(3);
        auto rows = torch::empty_like(src), out = torch::empty_like(src);
        for (int64_t p = 0; p < P; ++p) {
            const float* a = src.data_ptr<float>() + p * H * W;
            float* b = rows.data_ptr<float>() + p * H * W;
            running_max(a, b, H, W, 1, W, radius);                                  // along x
            running_max(b, out.data_ptr<float>() + p * H * W, W, H, W, 1, radius);  // along y
        }
        return out;
    }
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
