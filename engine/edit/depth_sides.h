#pragma once
// The depth fit's per-texel state (depth_fit.cpp) and the choice of an ambiguous texel's side of
// the focal plane by a parallax field (depth_sides.cpp); internal to engine/edit.
#include <vector>

namespace refocus::depth_detail {

// A texel's 1-D solve (depth_fit.cpp, solve_abs): the least cost's depth, and the smallest and
// largest depth within the tie tolerance of it.
struct Solution {
    double best, lo, hi;
    bool ambiguous(double gap = 0.5) const { return hi - lo > gap; }
};

// One atlas layer during the fit: texel depths and the frames' observations of each texel.
struct LayerFit {
    int W = 0, H = 0;
    std::vector<float> d;     // [H·W] inverse depth
    std::vector<float> seen;  // [H·W] total splat weight
    std::vector<int> start;   // CSR offsets into obs, [H·W + 1]
    struct TexObs {
        int t;
        float w, r;  // splat weight, weighted mean radius
    };
    std::vector<TexObs> obs;   // sorted by texel, then frame
    std::vector<float> gamma;  // [H·W] parallax (relative inverse depth); empty: none
};

// Where a texel's side of the focal plane is open (Solution::ambiguous), the side the layer's
// parallax field γ (LayerFit::gamma) says; writes L.d and returns true, or false where the
// field says nothing about this layer's depth. `confident` marks the texels the radius decided.
bool parallax_sides(LayerFit& L, const std::vector<Solution>& sols,
                    const std::vector<float>& confident);

}  // namespace refocus::depth_detail
