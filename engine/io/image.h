#pragma once
// Frames inside Refocus are linear-light float RGB, row-major, channels interleaved.
// sRGB lives only at the edges (decode on read, encode on write): blur happens in linear light.
#include <cstddef>
#include <string>
#include <vector>

namespace refocus {

struct Image {
    int width = 0;
    int height = 0;
    int channels = 0;
    std::vector<float> pixels;  // [height][width][channels]

    Image() = default;
    Image(int w, int h, int c, float fill = 0.0f)
        : width(w), height(h), channels(c), pixels(static_cast<size_t>(w) * h * c, fill) {}

    bool empty() const { return pixels.empty(); }
    size_t size() const { return pixels.size(); }
    float* data() { return pixels.data(); }
    const float* data() const { return pixels.data(); }
    float& at(int x, int y, int c) {
        return pixels[(static_cast<size_t>(y) * width + x) * channels + c];
    }
    float at(int x, int y, int c) const {
        return pixels[(static_cast<size_t>(y) * width + x) * channels + c];
    }
    bool same_shape(const Image& o) const {
        return width == o.width && height == o.height && channels == o.channels;
    }
};

// IEC 61966-2-1 transfer functions on [0,1] (values outside are clamped for the encode).
float srgb_to_linear(float v);
float linear_to_srgb(float v);

// Exact 8-bit decode table (256 entries).
const float* srgb8_to_linear_table();

// Linear float → sRGB-encoded 8-bit / 16-bit code values, rounded, clamped.
unsigned char linear_to_srgb8(float v);
unsigned short linear_to_srgb16(float v);

// Counts NaN/Inf values; `first` gets the index of the first one (or -1).
size_t count_nonfinite(const Image& img, long* first = nullptr);
// No real light is this bright in linear values (1.0 is diffuse white): a finite value beyond it
// is damage (1e30 in an EXR), treated as Inf is.
constexpr float kMaxLinearValue = 1e4f;
// Counts NaN/Inf and |x| > kMaxLinearValue; `first` as count_nonfinite's.
size_t count_unusable(const Image& img, long* first = nullptr);
// Replaces NaN and -Inf with 0, +Inf with the largest usable value in the image, and clamps the
// rest to ±kMaxLinearValue.
void clean_nonfinite(Image& img);

// Converts 1/3/4 channels to 3 (grey replicated, alpha dropped).
Image to_rgb(const Image& img);

}  // namespace refocus
