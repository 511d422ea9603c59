#include "io/image_file.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <vector>

#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

std::string oiio_error(const std::string& fallback) {
    std::string e = OIIO::geterror();
    if (e.empty()) return fallback;
    // OIIO errors can span lines; keep the message on one line.
    std::replace(e.begin(), e.end(), '\n', ' ');
    while (!e.empty() && e.back() == ' ') e.pop_back();
    return e;
}

}  // namespace

const char* const kNonFiniteCleanHint =
    "use --nonfinite clean to replace NaN/-Inf with 0 and clamp +Inf and values beyond 1e4 to "
    "1e4";

ImageReadResult read_image_file(const std::string& path, bool decode_srgb,
                                NonFinitePolicy nonfinite, int frame, const std::string& fix) {
    if (!fs::exists(path)) throw Error(file_error(path, "no such file", frame));
    // Alpha is dropped later, so colour must come as stored, not premultiplied by it.
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    if (!in)
        throw Error(file_error(path, "cannot open image: " + oiio_error("unknown format"), frame));
    const OIIO::ImageSpec& spec = in->spec();
    const int nch = spec.nchannels;
    if (nch != 1 && nch != 3 && nch != 4)
        throw Error(file_error(path,
                               "unsupported channel count " + std::to_string(nch) +
                                   " (need 1 = grey, 3 = RGB or 4 = RGBA)",
                               frame));
    if (spec.width <= 0 || spec.height <= 0)
        throw Error(file_error(path, "image has zero size", frame));

    ImageReadResult r;
    r.image = Image(spec.width, spec.height, nch);
    const OIIO::TypeDesc fmt = spec.format;
    const bool is_float = fmt.is_floating_point();
    r.format = is_float ? (fmt.size() == 2 ? "half" : "float")
                        : (fmt.size() == 1   ? "uint8"
                           : fmt.size() == 2 ? "uint16"
                                             : "uint32");
    // Some decoders (JPEG) fill a truncated file with grey and only leave an error behind.
    if (!in->read_image(0, 0, 0, nch, OIIO::TypeDesc::FLOAT, r.image.data()) || in->has_error()) {
        std::string why = in->geterror();
        if (why.empty()) why = oiio_error("read failed");
        std::replace(why.begin(), why.end(), '\n', ' ');
        throw Error(file_error(path, "cannot read pixels (truncated or corrupt?): " + why, frame));
    }
    in->close();

    std::string cs = spec.get_string_attribute("oiio:ColorSpace");
    bool stored_linear = is_float || cs == "linear" || cs == "Linear";
    r.linear = stored_linear || !decode_srgb;
    if (!stored_linear && decode_srgb) {
        // An alpha channel is coverage, not light: it keeps its stored value.
        const float* lut = srgb8_to_linear_table();
        const bool u8 = fmt == OIIO::TypeDesc::UINT8;
        for (size_t i = 0; i < r.image.pixels.size(); ++i) {
            if (nch == 4 && i % 4 == 3) continue;
            float& v = r.image.pixels[i];
            v = u8 ? lut[std::clamp(int(std::lround(v * 255.0f)), 0, 255)] : srgb_to_linear(v);
        }
    }

    long first = -1;
    size_t bad = count_unusable(r.image, &first);
    if (bad > 0) {
        if (nonfinite == NonFinitePolicy::Reject) {
            long px = first / nch;
            throw Error(file_error(path,
                                   std::to_string(bad) +
                                       " NaN/Inf or out-of-range (|x| > 1e4) value(s), first at "
                                       "pixel (" +
                                       std::to_string(px % spec.width) + ", " +
                                       std::to_string(px / spec.width) + "); rejected (" +
                                       (fix.empty() ? "fix or replace the file" : fix) + ")",
                                   frame));
        }
        clean_nonfinite(r.image);
    }
    return r;
}

PixelFormat parse_pixel_format(const std::string& name) {
    if (name == "png" || name == "png8") return PixelFormat::Png8;
    if (name == "png16") return PixelFormat::Png16;
    if (name == "tiff" || name == "tif" || name == "tiff16") return PixelFormat::Tiff16;
    if (name == "exr" || name == "exr16" || name == "half") return PixelFormat::ExrHalf;
    if (name == "exr32" || name == "float") return PixelFormat::ExrFloat;
    throw Error("unknown image format '" + name +
                "' (use png, png16, tiff, exr (half) or exr32 (float))");
}

const char* extension_of(PixelFormat f) {
    switch (f) {
        case PixelFormat::Png8:
        case PixelFormat::Png16:
            return "png";
        case PixelFormat::Tiff16:
            return "tiff";
        case PixelFormat::ExrHalf:
        case PixelFormat::ExrFloat:
            return "exr";
    }
    return "bin";
}

void write_image_file(const std::string& path, const Image& img, PixelFormat format,
                      bool srgb_encode, const char* exr_compression) {
    if (img.empty()) throw Error(file_error(path, "refusing to write an empty image"));
    const fs::path target(path);
    if (!target.parent_path().empty() && !fs::is_directory(target.parent_path()))
        throw Error(file_error(path, "folder does not exist"));
    const int nch = img.channels;
    OIIO::TypeDesc type;
    switch (format) {
        case PixelFormat::Png8:
            type = OIIO::TypeDesc::UINT8;
            break;
        case PixelFormat::Png16:
        case PixelFormat::Tiff16:
            type = OIIO::TypeDesc::UINT16;
            break;
        case PixelFormat::ExrHalf:
            type = OIIO::TypeDesc::HALF;
            break;
        case PixelFormat::ExrFloat:
            type = OIIO::TypeDesc::FLOAT;
            break;
    }
    OIIO::ImageSpec spec(img.width, img.height, nch, type);
    const bool is_float = format == PixelFormat::ExrHalf || format == PixelFormat::ExrFloat;
    std::vector<float> buf(img.pixels);
    if (!is_float) {
        for (size_t i = 0; i < buf.size(); ++i) {
            const bool alpha = nch == 4 && (i % 4) == 3;
            float v = buf[i];
            buf[i] = (srgb_encode && !alpha)
                         ? linear_to_srgb(v)
                         : (std::isfinite(v) ? std::clamp(v, 0.0f, 1.0f) : 0.0f);
        }
        spec.attribute("oiio:ColorSpace", srgb_encode ? "sRGB" : "linear");
    } else {
        spec.attribute("compression", exr_compression);
        spec.attribute("oiio:ColorSpace", "linear");
    }
    if (format == PixelFormat::Tiff16) spec.attribute("compression", "zip");

    fs::path tmp = temp_sibling(target);
    auto out = OIIO::ImageOutput::create(tmp.string());
    if (!out) throw Error(file_error(path, "no writer for this format: " + oiio_error("?")));
    // TIFF is left out: OIIO 2.4's TIFF writer produces a broken file through a proxy.
    if (format != PixelFormat::Tiff16 && out->supports("ioproxy")) {
        // Encode in memory, then one checked, atomic file write: every OS error (full disk)
        // is caught with its reason and the previous file stays.
        OIIO::Filesystem::IOVecOutput vec;
        bool ok = out->set_ioproxy(&vec) && out->open(tmp.string(), spec) &&
                  out->write_image(OIIO::TypeDesc::FLOAT, buf.data());
        std::string why = ok ? "" : out->geterror();
        ok = out->close() && ok;
        if (!ok) {
            if (why.empty()) why = out->geterror();
            std::replace(why.begin(), why.end(), '\n', ' ');
            throw Error(file_error(
                path, "cannot encode the image: " + (why.empty() ? "unknown error" : why)));
        }
        const auto& bytes = vec.buffer();
        write_file_atomic(target, std::string(bytes.begin(), bytes.end()));
        return;
    }
    if (!out->open(tmp.string(), spec)) {
        std::string why = oiio_error("open failed");
        std::error_code ec;
        fs::remove(tmp, ec);
        throw Error(file_error(path, "cannot write: " + why));
    }
    bool ok = out->write_image(OIIO::TypeDesc::FLOAT, buf.data());
    std::string why = ok ? "" : oiio_error("write failed");
    ok = out->close() && ok;
    if (!ok) {
        if (why.empty()) why = oiio_error("");
        if (why.empty()) why = std::strerror(errno);
        std::error_code ec;
        fs::remove(tmp, ec);
        throw Error(file_error(path, "write failed: " + why + " (the previous file is untouched)"));
    }
    // The data must be on disk before the rename publishes it (a crash leaves old or new).
    const int fd = ::open(tmp.c_str(), O_RDONLY);
    const bool synced = fd >= 0 && ::fsync(fd) == 0;
    if (fd >= 0) ::close(fd);
    if (!synced) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw Error(file_error(path, std::string("write failed: cannot sync the file to disk: ") +
                                         std::strerror(errno)));
    }
    commit_temp(tmp, target);
}

}  // namespace refocus
