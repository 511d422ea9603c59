#include "io/image.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "util/error.h"

namespace refocus {

float srgb_to_linear(float v) {
    if (v <= 0.04045f) return v / 12.92f;
    return std::pow((v + 0.055f) / 1.055f, 2.4f);
}

float linear_to_srgb(float v) {
    if (!(v > 0.0f)) return 0.0f;  // also maps NaN to 0
    if (v >= 1.0f) return 1.0f;
    if (v <= 0.0031308f) return v * 12.92f;
    return 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

const float* srgb8_to_linear_table() {
    static const std::array<float, 256> table = [] {
        std::array<float, 256> t{};
        for (int i = 0; i < 256; ++i) t[i] = srgb_to_linear(i / 255.0f);
        return t;
    }();
    return table.data();
}

unsigned char linear_to_srgb8(float v) {
    return static_cast<unsigned char>(std::lround(linear_to_srgb(v) * 255.0f));
}

unsigned short linear_to_srgb16(float v) {
    return static_cast<unsigned short>(std::lround(linear_to_srgb(v) * 65535.0f));
}

size_t count_nonfinite(const Image& img, long* first) {
    size_t n = 0;
    if (first) *first = -1;
    for (size_t i = 0; i < img.pixels.size(); ++i) {
        if (!std::isfinite(img.pixels[i])) {
            if (n == 0 && first) *first = static_cast<long>(i);
            ++n;
        }
    }
    return n;
}

size_t count_unusable(const Image& img, long* first) {
    size_t n = 0;
    if (first) *first = -1;
    for (size_t i = 0; i < img.pixels.size(); ++i) {
        const float v = img.pixels[i];
        if (!(std::fabs(v) <= kMaxLinearValue)) {  // NaN fails the test too
            if (n == 0 && first) *first = static_cast<long>(i);
            ++n;
        }
    }
    return n;
}

void clean_nonfinite(Image& img) {
    float maxv = 0.0f;
    for (float v : img.pixels)
        if (std::fabs(v) <= kMaxLinearValue) maxv = std::max(maxv, v);
    for (float& v : img.pixels) {
        if (std::isnan(v))
            v = 0.0f;
        else if (std::isinf(v))
            v = v > 0 ? maxv : 0.0f;
        else
            v = std::clamp(v, -kMaxLinearValue, kMaxLinearValue);
    }
}

Image to_rgb(const Image& img) {
    if (img.channels == 3) return img;
    if (img.channels != 1 && img.channels != 4)
        throw Error("cannot convert a " + std::to_string(img.channels) + "-channel image to RGB");
    Image out(img.width, img.height, 3);
    size_t n = static_cast<size_t>(img.width) * img.height;
    for (size_t i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c)
            out.pixels[i * 3 + c] = img.pixels[i * img.channels + (img.channels == 1 ? 0 : c)];
    return out;
}

}  // namespace refocus
