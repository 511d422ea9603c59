#include "fit/crops.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>

namespace refocus {

namespace F = torch::nn::functional;

namespace {

// splitmix64 (Steele, Lea & Flood 2014): a stateless, well-mixed hash.
uint64_t mix(uint64_t z) {
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

// An axis of `length` px cut into n tiles of ⌈length / n⌉ px, evenly spaced from 0 to the end.
struct Tiling {
    int64_t length = 0, n = 1, size = 0;
    Tiling(int64_t len, int64_t crop_px, bool one_more) : length(len), size(len) {
        if (crop_px <= 0 || length <= crop_px) return;
        n = length / crop_px + (one_more ? 1 : 0);
        size = (length + n - 1) / n;
    }
    int64_t at(uint64_t draw) const {
        if (n == 1) return 0;
        const int64_t k = int64_t(draw % uint64_t(n));
        return std::llround(double(k) * double(length - size) / double(n - 1));
    }
};

}  // namespace

Crops draw_crops(int64_t width, int64_t height, int64_t crop_px, uint64_t seed, int64_t step,
                 size_t frames) {
    const uint64_t key = mix(seed ^ mix(uint64_t(step)));
    const Tiling tx(width, crop_px, key & 1), ty(height, crop_px, key & 2);
    Crops c;
    c.w = tx.size;
    c.h = ty.size;
    c.whole = tx.n == 1 && ty.n == 1;
    for (size_t b = 0; b < frames; ++b) {
        const uint64_t h = mix(key + b + 1);
        c.x.push_back(tx.at(h & 0xffffffffull));
        c.y.push_back(ty.at(h >> 32));
    }
    return c;
}

Crops grow_crops(const Crops& c, int64_t width, int64_t height, int64_t margin) {
    Crops g;
    g.w = std::min(c.w + 2 * margin, width);
    g.h = std::min(c.h + 2 * margin, height);
    g.whole = c.whole;
    for (size_t b = 0; b < c.x.size(); ++b) {
        g.x.push_back(std::clamp(c.x[b] - margin, int64_t(0), width - g.w));
        g.y.push_back(std::clamp(c.y[b] - margin, int64_t(0), height - g.h));
    }
    return g;
}

Windows crop_windows(const Crops& c, int64_t width, int64_t height, int64_t margin, int64_t pad) {
    Windows w;
    w.w = std::min(c.w + 2 * margin, width + 2 * pad);
    w.h = std::min(c.h + 2 * margin, height + 2 * pad);
    for (size_t b = 0; b < c.x.size(); ++b) {
        w.x0.push_back(std::clamp(c.x[b] - margin, -pad, width + pad - w.w));
        w.y0.push_back(std::clamp(c.y[b] - margin, -pad, height + pad - w.h));
    }
    return w;
}

torch::Tensor window_pixels(const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                            int64_t h, int64_t w) {
    std::vector<torch::Tensor> per;
    for (size_t b = 0; b < x0.size(); ++b) {
        auto ys = torch::arange(y0[b], y0[b] + h, torch::kFloat32),
             xs = torch::arange(x0[b], x0[b] + w, torch::kFloat32);
        auto g = torch::meshgrid({ys, xs}, "ij");
        per.push_back(torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({h * w})}, 0));
    }
    return torch::stack(per);
}

torch::Tensor upsample_window(const torch::Tensor& x, int64_t H, int64_t W,
                              const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                              int64_t h, int64_t w, bool corners) {
    // grid_sample reads the same bilinear weights as interpolate: with align_corners the
    // frame's pixel i sits at 2i/(L − 1) − 1, without at (2i + 1)/L − 1; pixels past the frame
    // take its edge (the coordinates are clamped), as pad_edges does.
    auto coord = [&](int64_t from, int64_t n, int64_t L) {
        auto i = torch::arange(from, from + n, torch::kFloat32).clamp(0, L - 1);
        if (corners) return L > 1 ? 2.0 * i / double(L - 1) - 1.0 : torch::zeros_like(i);
        return (2.0 * i + 1.0) / double(L) - 1.0;
    };
    std::vector<torch::Tensor> grids;
    for (size_t b = 0; b < x0.size(); ++b) {
        auto gx = coord(x0[b], w, W).view({1, w}).expand({h, w});
        auto gy = coord(y0[b], h, H).view({h, 1}).expand({h, w});
        grids.push_back(torch::stack({gx, gy}, 2));
    }
    return F::grid_sample(x, torch::stack(grids),
                          F::GridSampleFuncOptions()
                              .mode(torch::kBilinear)
                              .padding_mode(torch::kBorder)
                              .align_corners(corners));
}

}  // namespace refocus
