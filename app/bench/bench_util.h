#pragma once
// Helpers shared by the synth-clip benchmarks (bench kernel, bench bound).
#include <torch/torch.h>

#include <sstream>
#include <string>
#include <vector>

namespace refocus {

// Linear light [C,H,W] → sRGB 8-bit code values (0..255, rounded), as the metrics score.
inline torch::Tensor srgb8(const torch::Tensor& x) {
    auto c = x.clamp(0, 1);
    auto s = torch::where(c <= 0.0031308, 12.92 * c, 1.055 * c.pow(1.0 / 2.4) - 0.055);
    return (s * 255).round();
}

// "0.5,1,2" → {0.5, 1, 2}.
inline std::vector<double> parse_list(const std::string& s) {
    std::vector<double> v;
    std::stringstream ss(s);
    std::string item;
    while (std::getline(ss, item, ',')) v.push_back(std::stod(item));
    return v;
}

}  // namespace refocus
