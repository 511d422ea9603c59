#pragma once
// Dense optical flow between consecutive frames (OpenCV DIS, Kroeger et al. 2016) and the
// forward-backward consistency test that marks occluded / unreliable pixels.
//
// Conventions (used throughout engine/prepare): a flow image is 2-channel float (u, v) in px;
// pixel centres are at integer coordinates; flow f from frame a to frame b means that the pixel
// at x in frame a is seen at x + f(x) in frame b (a(x) ≈ b(x + f(x))).
#include <vector>

#include "io/image.h"

namespace refocus {

enum class FlowPreset { Fast, Medium, Fine };  // cv::DISOpticalFlow::PRESET_*

struct FlowOptions {
    FlowPreset preset = FlowPreset::Fine;
    // Consistency (Sundaram, Brox & Keutzer 2010, eq. 5):
    //   |f(x) + b(x + f(x))|² < alpha·(|f(x)|² + |b(x + f(x))|²) + beta
    // The relative term tolerates the error of large motions; beta (px²) the error of small ones.
    double consistency_alpha = 0.01;
    double consistency_beta = 0.5;
};

// Flow from `from` to `to` (linear RGB frames of one size) → 2-channel image (u, v).
Image compute_flow(const Image& from, const Image& to, const FlowOptions& opts = {});

// 1 where `fwd` (a→b) and `bwd` (b→a) agree at x and x + fwd(x) lands inside the frame, else 0.
// Single-channel image of fwd's size.
Image flow_consistency(const Image& fwd, const Image& bwd, const FlowOptions& opts = {});

// Flows of a clip: fwd[t] = flow t → t+1, bwd[t] = flow t+1 → t, with their consistency masks
// (fwd_valid[t] over frame t, bwd_valid[t] over frame t+1), t in [0, frames − 1).
struct ClipFlow {
    std::vector<Image> fwd, bwd;
    std::vector<Image> fwd_valid, bwd_valid;
};
ClipFlow compute_clip_flow(const std::vector<Image>& frames, const FlowOptions& opts = {});

}  // namespace refocus
