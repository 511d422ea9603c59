#pragma once
// Conversions between refocus::Image (HWC, float) and LibTorch tensors (CHW, float32).
#include <torch/types.h>

#include <vector>

#include "io/image.h"

namespace refocus {

torch::Tensor image_to_tensor(const Image& img);             // → [C,H,W] float32
Image tensor_to_image(const torch::Tensor& t);               // [C,H,W] or [H,W] → Image
torch::Tensor stack_images(const std::vector<Image>& imgs);  // → [T,C,H,W]

}  // namespace refocus
