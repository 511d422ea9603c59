#pragma once
// Linear RGB images as sRGB textures for Dear ImGui to draw (the viewer, the time slice).
#include "io/image.h"

namespace refocus {

// Creates `tex` when it is 0, else replaces its image; `w` and `h` receive the image's size.
void upload_texture(unsigned& tex, const Image& linear_rgb, int& w, int& h);

}  // namespace refocus
