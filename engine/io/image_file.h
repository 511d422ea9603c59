#pragma once
// Single image files through OpenImageIO: PNG, JPEG, TIFF, OpenEXR.
#include <string>

#include "io/image.h"

namespace refocus {

enum class NonFinitePolicy { Reject, Clean };

struct ImageReadResult {
    Image image;         // float, channels as stored (1..4)
    bool linear = true;  // true: values are linear light as stored (float/half formats)
    std::string format;  // "uint8", "uint16", "half", "float"
};

// Reads `path` as float. Integer-coded formats (8/16-bit PNG, JPEG, TIFF) are sRGB-encoded and
// decoded to linear when `decode_srgb`; float formats (EXR, float TIFF) are taken as linear.
// NaN/Inf and absurd finite values (|x| > kMaxLinearValue): Reject throws (naming the file, the
// count, the first pixel and `fix`, what the user can do); Clean replaces them (clean_nonfinite).
// `frame` only labels messages.
ImageReadResult read_image_file(const std::string& path, bool decode_srgb = true,
                                NonFinitePolicy nonfinite = NonFinitePolicy::Reject, int frame = -1,
                                const std::string& fix = "");
// The --nonfinite clean advice, for the commands that take the option (new, info).
extern const char* const kNonFiniteCleanHint;

// Storage of a written image. The sRGB-coded ones encode linear input; the float ones store it.
enum class PixelFormat { Png8, Png16, Tiff16, ExrHalf, ExrFloat };

// Parses "png"/"png8", "png16", "tiff"/"tiff16", "exr"/"exr16"/"half", "exr32"/"float".
PixelFormat parse_pixel_format(const std::string& name);
const char* extension_of(PixelFormat f);

// Writes atomically (complete or absent). `srgb_encode` = false writes data passes (alpha,
// masks) with their values as they are, scaled to the integer range. `exr_compression`: an
// OpenEXR lossless codec; the frame cache uses "piz" (no zlib: the ingest's largest cost with
// "zip", and smaller files on camera frames).
void write_image_file(const std::string& path, const Image& img, PixelFormat format,
                      bool srgb_encode = true, const char* exr_compression = "zip");

}  // namespace refocus
