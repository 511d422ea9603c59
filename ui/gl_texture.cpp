#include "gl_texture.h"

#include <GL/gl.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace refocus {

std::vector<unsigned char> to_rgba8(const Image& img) {
    std::vector<unsigned char> px(static_cast<size_t>(img.width) * img.height * 4, 255);
    for (size_t i = 0; i < static_cast<size_t>(img.width) * img.height; ++i)
        for (int c = 0; c < 3; ++c) {
            float v = img.pixels[i * img.channels + std::min(c, img.channels - 1)];
            if (!std::isfinite(v)) v = 0.0f;
            px[i * 4 + c] = static_cast<unsigned char>(std::lround(linear_to_srgb(v) * 255.0f));
        }
    return px;
}

void upload_texture(unsigned& tex, const Image& img, int& w, int& h) {
    upload_rgba8(tex, to_rgba8(img).data(), img.width, img.height);
    w = img.width;
    h = img.height;
}

void upload_rgba8(unsigned& tex, const unsigned char* px, int w, int h) {
    if (!tex) glGenTextures(1, &tex);
    glBindTexture(GL_TEXTURE_2D, tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, w, h, 0, GL_RGBA, GL_UNSIGNED_BYTE, px);
}

}  // namespace refocus
