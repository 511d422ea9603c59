#pragma once
// The clip's noise: a standard deviation per channel in 8-bit sRGB levels (docs/method.md,
// Noise). The fit's "explained" test compares its residual with it, and the output rules
// decide from it how far deconvolution is trusted.
//
// Estimator: the diagonal Haar detail HH = (a − b − c + d)/2 of each 2x2 cell has the noise's σ
// (the transform is orthonormal) and almost none of a blurred or smooth image. Cells are kept
// where the cell means around them (LL, independent of HH under white noise) are flattest, so
// texture and edges do not count; cells that touch a clipped value are left out; cells align
// with H.264's 4x4/8x8 blocks, whose edges fall between cells. σ is a trimmed mean of |HH|
// (lowest 95 %, scaled for a Gaussian), the sources' rounding (1/12 level² for 8-bit) taken
// out, and the least over up to 9 frames spread over the clip (texture in focus reads as noise;
// the sensor's noise is every frame's floor).
#include <nlohmann/json.hpp>

#include <array>
#include <string>
#include <vector>

#include "io/image.h"

namespace refocus {

struct Project;

struct NoiseEstimate {
    std::array<double, 3> sigma{{-1, -1, -1}};  // 8-bit levels per channel; < 0: not measured
    int frames = 0;                             // frames measured
    bool measured() const { return sigma[0] >= 0; }
    double mean() const { return (sigma[0] + sigma[1] + sigma[2]) / 3.0; }
    std::string describe() const;  // "σ 1.52 levels (R 1.50, G 1.49, B 1.58; 9 frames)"
    nlohmann::json to_json() const;
    // Refuses a malformed section with refocus::Error naming `label`.
    static NoiseEstimate from_json(const nlohmann::json& j, const std::string& label);
};

// One frame's σ per channel (levels) from a linear RGB frame; `rounding_var` is the source's
// quantisation variance in levels² (1/12 for 8-bit, 0 for float). Negative where the frame has
// too few usable cells (under 64).
std::array<double, 3> frame_noise_levels(const Image& linear, double rounding_var);

// The quantisation variance of a source format ("uint8", "uint16", "half", "float").
double source_rounding_var(const std::string& source_format);

// The least over frames of frame_noise_levels (frames with no estimate left out).
NoiseEstimate combine_frame_noise(const std::vector<std::array<double, 3>>& per_frame);

// Which frames to measure in a clip of `frames`: up to 9, spread evenly.
std::vector<int> noise_sample_frames(int frames);

// The project's stored estimate (project.json "noise"), or, for a project made before it was
// stored, one measured from its cached frames now (not stored).
NoiseEstimate project_noise(const Project& p);
NoiseEstimate measure_project_noise(const Project& p);

}  // namespace refocus
