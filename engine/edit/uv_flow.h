#pragma once
// Optical flow from the fitted mappings ([paper] §5.2): the forward flow of frame t is where
// each pixel's atlas point is seen again in frame t+1. Each pixel follows its layer (the
// subject where alpha > 1/2); the point is found in t+1 by Newton's method on t+1's atlas
// coordinates, so a pixel that leaves the frame still gets the flow its mapping implies.
#include "io/image.h"
#include "model/fit_model.h"

namespace refocus {

// `a`: frame t's layers, `b`: frame t+1's (batch 1 each, whole frames). 3 channels: the flow
// (dx, dy) in px and 0.
Image uv_flow(const Layers& a, const Layers& b);

}  // namespace refocus
