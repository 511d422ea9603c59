#pragma once
// Linear RGB images as sRGB textures for Dear ImGui to draw (the viewer, the time slice).
#include <vector>

#include "io/image.h"

namespace refocus {

// Creates `tex` when it is 0, else replaces its image; `w` and `h` receive the image's size.
void upload_texture(unsigned& tex, const Image& linear_rgb, int& w, int& h);
// The same for pixels already in sRGB RGBA8 (w * h * 4 bytes).
void upload_rgba8(unsigned& tex, const unsigned char* rgba, int w, int h);
// sRGB RGBA8 of a linear image for display (a grey image shows grey); thread-safe, no GL.
std::vector<unsigned char> to_rgba8(const Image& linear);

}  // namespace refocus
