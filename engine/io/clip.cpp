#include "io/clip.h"

#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <map>
#include <regex>

#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
    return s;
}

bool is_image_ext(const std::string& ext) {
    static const char* exts[] = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr"};
    std::string e = lower(ext);
    return std::any_of(std::begin(exts), std::end(exts), [&](const char* x) { return e == x; });
}

// ---------------------------------------------------------------- video
class VideoReader : public ClipReader {
  public:
    VideoReader(const std::string& path, const ClipReadOptions& opts) : m_path(path) {
        reopen();
        m_info.path = path;
        m_info.kind = "video";
        m_info.fps = m_cap.get(cv::CAP_PROP_FPS);
        if (!(m_info.fps > 0.0) || !std::isfinite(m_info.fps)) m_info.fps = opts.default_fps;
        m_info.stream_fps = m_info.fps;
        if (opts.fps_override) m_info.fps = opts.default_fps;
        m_info.width = static_cast<int>(m_cap.get(cv::CAP_PROP_FRAME_WIDTH));
        m_info.height = static_cast<int>(m_cap.get(cv::CAP_PROP_FRAME_HEIGHT));
        m_info.source_channels = 3;
        m_info.source_format = "uint8";
        m_info.source_linear = false;
        const double header_frames = m_cap.get(cv::CAP_PROP_FRAME_COUNT);
        // Count what actually decodes: a truncated file's header promises more.
        int n = 0;
        while (m_cap.grab()) ++n;
        if (n == 0) throw Error(file_error(path, "no decodable frames (empty or corrupt video)"));
        if (header_frames > 0 && n + 1 < static_cast<int>(header_frames)) {
            // MP4/MOV index every frame, so fewer is a cut file; Matroska, WebM and AVI give a
            // count estimated from the duration, which a variable frame rate throws off.
            const std::string ext = lower(fs::path(path).extension().string());
            const std::string counts = std::to_string(static_cast<int>(header_frames)) +
                                       " frames but " + std::to_string(n) + " decode";
            if (ext == ".mp4" || ext == ".mov" || ext == ".m4v")
                throw Error(file_error(path, "truncated: the header lists " + counts));
            m_info.note = "the container's duration suggests " + counts +
                          " (a variable frame rate, or a cut file): all " + std::to_string(n) +
                          " decoded frames are used";
        }
        m_info.frames = n;
        reopen();
    }

    Image read(int index) override {
        if (index < 0 || index >= m_info.frames)
            throw Error(file_error(m_path, "frame index out of range", index));
        if (index < m_next) reopen();
        while (m_next < index) {
            if (!m_cap.grab()) throw Error(file_error(m_path, "cannot decode frame", m_next));
            ++m_next;
        }
        cv::Mat bgr;
        if (!m_cap.read(bgr) || bgr.empty())
            throw Error(file_error(m_path, "cannot decode frame", index));
        ++m_next;
        if (bgr.cols != m_info.width || bgr.rows != m_info.height)
            throw Error(file_error(m_path, "frame size changed mid-stream", index));
        Image out(bgr.cols, bgr.rows, 3);
        const float* lut = srgb8_to_linear_table();
        for (int y = 0; y < bgr.rows; ++y) {
            const unsigned char* row = bgr.ptr<unsigned char>(y);
            float* dst = out.data() + static_cast<size_t>(y) * bgr.cols * 3;
            for (int x = 0; x < bgr.cols; ++x) {
                dst[3 * x + 0] = lut[row[3 * x + 2]];
                dst[3 * x + 1] = lut[row[3 * x + 1]];
                dst[3 * x + 2] = lut[row[3 * x + 0]];
            }
        }
        return out;
    }

  private:
    void reopen() {
        m_cap.release();
        if (!m_cap.open(m_path, cv::CAP_FFMPEG) || !m_cap.isOpened())
            throw Error(file_error(m_path, "cannot open video (unsupported or corrupt file)"));
        m_next = 0;
    }
    std::string m_path;
    cv::VideoCapture m_cap;
    int m_next = 0;
};

// ---------------------------------------------------------------- sequences
// Turns a frame pattern "dir/frame_%04d.exr" into (dir, regex over file names). Only the file
// name may hold the frame number.
std::pair<fs::path, std::regex> pattern_regex(const std::string& pattern) {
    fs::path p(pattern);
    if (p.parent_path().string().find('%') != std::string::npos)
        throw Error(
            file_error(pattern, "the frame number (%d) must be in the file name, not the folder"));
    const FramePattern fp = parse_frame_pattern(p.filename().string(), pattern);
    auto escape = [](const std::string& s) {
        static const std::regex special(R"([.^$|()\[\]{}*+?\\])");
        return std::regex_replace(s, special, R"(\$&)");
    };
    std::string digits = fp.width == 0 ? "(\\d+)" : "(\\d{" + std::to_string(fp.width) + ",})";
    std::string re = "^" + escape(fp.prefix) + digits + escape(fp.suffix) + "$";
    return {p.parent_path(), std::regex(re)};
}

// Frame numbers must run without gaps or repeats ("f_3.png" and "f_03.png" are both frame 3).
void check_numbering(const std::string& path,
                     const std::vector<std::pair<long, std::string>>& sorted) {
    for (size_t i = 1; i < sorted.size(); ++i) {
        if (sorted[i].first == sorted[i - 1].first)
            throw Error(
                file_error(path, "two files have frame number " + std::to_string(sorted[i].first) +
                                     ": " + fs::path(sorted[i - 1].second).filename().string() +
                                     " and " + fs::path(sorted[i].second).filename().string()));
        if (sorted[i].first != sorted[i - 1].first + 1)
            throw Error(file_error(
                path, "sequence has a gap: frame number " +
                          std::to_string(sorted[i - 1].first + 1) + " is missing (after " +
                          fs::path(sorted[i - 1].second).filename().string() + ")"));
    }
}

class SequenceReader : public ClipReader {
  public:
    SequenceReader(const std::string& path, const ClipReadOptions& opts) : m_opts(opts) {
        m_info.path = path;
        m_info.kind = "sequence";
        m_info.fps = opts.default_fps;
        std::vector<std::pair<long, std::string>> indexed;
        if (path.find('%') != std::string::npos && !fs::exists(path)) {
            auto [dir, re] = pattern_regex(path);
            fs::path d = dir.empty() ? fs::path(".") : dir;
            if (!fs::is_directory(d)) throw Error(file_error(path, "folder does not exist"));
            for (const auto& e : fs::directory_iterator(d)) {
                std::string fname = e.path().filename().string();
                std::smatch m;
                if (std::regex_match(fname, m, re) && m[1].length() <= 15)
                    indexed.emplace_back(std::stol(m[1].str()), (dir / fname).string());
            }
            std::sort(indexed.begin(), indexed.end());
            check_numbering(path, indexed);
        } else if (fs::is_directory(path)) {
            std::map<std::string, int> exts;
            for (const auto& e : fs::directory_iterator(path)) {
                if (!e.is_regular_file() || !is_image_ext(e.path().extension().string())) continue;
                if (e.path().filename().string()[0] == '.') continue;
                exts[lower(e.path().extension().string())]++;
                indexed.emplace_back(0, e.path().string());
            }
            if (exts.size() > 1)
                throw Error(file_error(path, "folder mixes image types; pass a pattern such as " +
                                                 path + "/frame_%04d.png"));
            // Natural order: compare by the last run of digits, then by name.
            auto key = [](const std::string& s) {
                std::string stem = fs::path(s).stem().string();
                size_t end = stem.find_last_of("0123456789");
                if (end == std::string::npos) return -1L;
                size_t begin = stem.find_last_not_of("0123456789", end);
                begin = begin == std::string::npos ? 0 : begin + 1;
                return std::stol(stem.substr(begin, std::min<size_t>(end - begin + 1, 15)));
            };
            for (auto& f : indexed) f.first = key(f.second);
            std::sort(indexed.begin(), indexed.end());
            // Numbered frames (every name has a number) must form one run.
            if (!indexed.empty() && indexed.front().first >= 0) check_numbering(path, indexed);
        } else {
            indexed.emplace_back(0, path);  // a single image is a one-frame clip
        }
        if (indexed.empty()) throw Error(file_error(path, "no frames found (zero frames)"));
        for (auto& f : indexed) m_info.files.push_back(f.second);
        m_info.frames = static_cast<int>(m_info.files.size());

        // Validate every header without decoding pixels: one size, supported channels.
        for (int i = 0; i < m_info.frames; ++i) {
            const std::string& f = m_info.files[i];
            auto in = OIIO::ImageInput::open(f);
            if (!in) {
                std::string e = OIIO::geterror();
                std::replace(e.begin(), e.end(), '\n', ' ');
                throw Error(file_error(f, "cannot open image: " + e, i));
            }
            const auto& spec = in->spec();
            if (i == 0) {
                m_info.width = spec.width;
                m_info.height = spec.height;
                m_info.source_channels = spec.nchannels;
                const auto t = spec.format;
                m_info.source_format = t.is_floating_point() ? (t.size() == 2 ? "half" : "float")
                                                             : (t.size() == 1 ? "uint8" : "uint16");
                m_info.source_linear = t.is_floating_point();
            } else if (spec.width != m_info.width || spec.height != m_info.height) {
                throw Error(file_error(
                    f,
                    "frame size " + std::to_string(spec.width) + "x" + std::to_string(spec.height) +
                        " differs from the first frame's " + std::to_string(m_info.width) + "x" +
                        std::to_string(m_info.height),
                    i));
            }
            if (spec.nchannels != 1 && spec.nchannels != 3 && spec.nchannels != 4)
                throw Error(file_error(f,
                                       "unsupported channel count " +
                                           std::to_string(spec.nchannels) +
                                           " (need 1 = grey, 3 = RGB or 4 = RGBA)",
                                       i));
        }
    }

    Image read(int index) override {
        if (index < 0 || index >= m_info.frames)
            throw Error(file_error(m_info.path, "frame index out of range", index));
        const std::string& f = m_info.files[index];
        ImageReadResult r = read_image_file(f, true, m_opts.nonfinite, index, kNonFiniteCleanHint);
        if (r.image.width != m_info.width || r.image.height != m_info.height)
            throw Error(file_error(f, "frame size differs from the first frame's", index));
        return to_rgb(r.image);
    }

  private:
    ClipReadOptions m_opts;
};

}  // namespace

bool is_video_path(const std::string& path) {
    if (fs::is_directory(path)) return false;
    if (path.find('%') != std::string::npos && !fs::is_regular_file(path)) return false;
    std::string e = lower(fs::path(path).extension().string());
    return !e.empty() && !is_image_ext(e);
}

std::unique_ptr<ClipReader> ClipReader::open(const std::string& path, const ClipReadOptions& opts) {
    if (path.empty()) throw Error("no clip path given");
    if (path.find('%') == std::string::npos && !fs::exists(path))
        throw Error(file_error(path, "no such file or folder"));
    if (path.find('%') != std::string::npos && !fs::exists(path)) {
        // Not a file: a frame pattern of images, refused here when malformed.
        const std::string ext = fs::path(path).extension().string();
        if (!ext.empty() && !is_image_ext(ext))
            throw Error(file_error(path,
                                   "no such file (a frame pattern names images: png, jpg, "
                                   "tif or exr)"));
        const std::string why = frame_pattern_problem(fs::path(path).filename().string());
        if (!why.empty()) throw Error(file_error(path, "bad frame pattern: " + why));
    }
    if (is_video_path(path)) {
        if (fs::file_size(path) == 0) throw Error(file_error(path, "file is empty (zero frames)"));
        return std::make_unique<VideoReader>(path, opts);
    }
    return std::make_unique<SequenceReader>(path, opts);
}

std::vector<Image> read_all_frames(const std::string& path, const ClipReadOptions& opts,
                                   ClipInfo* info) {
    auto reader = ClipReader::open(path, opts);
    std::vector<Image> frames;
    frames.reserve(reader->info().frames);
    for (int i = 0; i < reader->info().frames; ++i) frames.push_back(reader->read(i));
    if (info) *info = reader->info();
    return frames;
}

// ---------------------------------------------------------------- writing
ClipFormat parse_clip_format(const std::string& name) {
    if (name == "mp4") return ClipFormat::Mp4;
    switch (parse_pixel_format(name)) {
        case PixelFormat::Png8:
            return ClipFormat::Png8;
        case PixelFormat::Png16:
            return ClipFormat::Png16;
        case PixelFormat::Tiff16:
            return ClipFormat::Tiff16;
        case PixelFormat::ExrHalf:
            return ClipFormat::ExrHalf;
        case PixelFormat::ExrFloat:
            return ClipFormat::ExrFloat;
    }
    return ClipFormat::Png8;
}

namespace {
PixelFormat pixel_format_of(ClipFormat f) {
    switch (f) {
        case ClipFormat::Png8:
            return PixelFormat::Png8;
        case ClipFormat::Png16:
            return PixelFormat::Png16;
        case ClipFormat::Tiff16:
            return PixelFormat::Tiff16;
        case ClipFormat::ExrHalf:
            return PixelFormat::ExrHalf;
        case ClipFormat::ExrFloat:
            return PixelFormat::ExrFloat;
        case ClipFormat::Mp4:
            break;
    }
    throw Error("mp4 is not an image format");
}
}  // namespace

std::string ClipWriter::sequence_path(const std::string& dir, const std::string& name, int index,
                                      ClipFormat format) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "_%04d.", index);
    return (fs::path(dir) / (name + buf + extension_of(pixel_format_of(format)))).string();
}

ClipWriter::ClipWriter(const std::string& target, const std::string& name, ClipFormat format,
                       const ClipWriteOptions& opts)
    : m_target(target), m_name(name), m_format(format), m_opts(opts) {
    if (format == ClipFormat::Mp4) {
        fs::path p(target);
        if (!p.parent_path().empty() && !fs::is_directory(p.parent_path()))
            throw Error(file_error(target, "folder does not exist"));
        remove_stale_temporaries(p.parent_path());  // a killed export's partial mp4
    } else {
        std::error_code ec;
        fs::create_directories(target, ec);
        if (!fs::is_directory(target))
            throw Error(file_error(target, "cannot create output folder: " + ec.message()));
        remove_stale_temporaries(target);  // a killed export's staging folder
    }
}

ClipWriter::~ClipWriter() {
    if (!m_done) cancel();
}

void ClipWriter::open_encoder(int w, int h) {
    m_tmp = temp_sibling(m_target).string();
    // 4:2:0 needs even sizes; odd ones get 4:4:4 so that the size is kept exactly. The RGB→YUV
    // matrix is BT.601 and tagged as such, which is also what OpenCV's reader assumes, so a
    // write-read round trip has no colour shift.
    const bool even = (w % 2 == 0) && (h % 2 == 0);
    char rate[32];
    std::snprintf(rate, sizeof rate, "%.6f", m_opts.fps);
    const std::vector<std::string> argv = {
        "ffmpeg", "-nostdin", "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo",
        "-pix_fmt", "rgb24", "-s", std::to_string(w) + "x" + std::to_string(h), "-r", rate, "-i",
        "pipe:0", "-an", "-c:v", "libx264", "-preset", "medium", "-crf", std::to_string(m_opts.crf),
        "-vf", "scale=out_color_matrix=bt601:out_range=tv:flags=accurate_rnd+full_chroma_int",
        "-pix_fmt", even ? "yuv420p" : "yuv444p", "-colorspace", "smpte170m", "-color_primaries",
        "bt709", "-color_trc", "iec61966-2-1", "-movflags", "+faststart", "-f", "mp4",
        // "file:" keeps a name with ':' or a leading '-' a plain file name.
        "file:" + m_tmp};
    try {
        m_encoder = std::make_unique<Subprocess>(argv);
    } catch (const Error& e) {
        throw Error(file_error(m_target, std::string("video encoder: ") + e.what()));
    }
}

namespace {
// The encoder's failure as one line: ffmpeg's last message, or the exit status.
std::string encoder_failure(Subprocess& enc, int status) {
    std::string line = enc.last_line();
    if (line.size() > 300) line = line.substr(0, 300) + "...";
    return "video encoder (ffmpeg) failed" +
           (line.empty() ? " with exit status " + std::to_string(status) : ": " + line) +
           " (the previous file is untouched)";
}
}  // namespace

bool mp4_has_moov(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    bool found = false;
    unsigned char h[16];
    long long pos = 0;
    for (int boxes = 0; boxes < 1000 && !found; ++boxes) {
        if (std::fseek(f, static_cast<long>(pos), SEEK_SET) != 0 || std::fread(h, 1, 8, f) != 8)
            break;
        unsigned long long size =
            (static_cast<unsigned long long>(h[0]) << 24) | (h[1] << 16) | (h[2] << 8) | h[3];
        if (std::memcmp(h + 4, "moov", 4) == 0) found = true;
        if (size == 1) {
            if (std::fread(h + 8, 1, 8, f) != 8) break;
            size = 0;
            for (int i = 8; i < 16; ++i) size = (size << 8) | h[i];
        }
        if (size < 8) break;  // 0: "to the end of file"
        pos += static_cast<long long>(size);
    }
    std::fclose(f);
    return found;
}

void ClipWriter::write(const Image& frame) {
    if (m_done) throw Error(file_error(m_target, "writer already finished"));
    if (m_count == 0) {
        m_width = frame.width;
        m_height = frame.height;
    } else if (frame.width != m_width || frame.height != m_height) {
        throw Error(file_error(m_target, "frame size changed while writing", m_count));
    }
    if (m_format == ClipFormat::Mp4) {
        if (frame.channels != 3) throw Error(file_error(m_target, "mp4 frames must be RGB"));
        if (!m_encoder) open_encoder(frame.width, frame.height);
        std::vector<unsigned char> rgb(frame.size());
        for (size_t i = 0; i < rgb.size(); ++i)
            rgb[i] = m_opts.srgb_encode ? linear_to_srgb8(frame.pixels[i])
                                        : static_cast<unsigned char>(std::lround(
                                              std::clamp(frame.pixels[i], 0.0f, 1.0f) * 255.0f));
        if (!m_encoder->write_stdin(rgb.data(), rgb.size())) {
            const int status = m_encoder->wait();
            const std::string why = encoder_failure(*m_encoder, status);
            cancel();
            throw Error(file_error(m_target, why, m_count));
        }
    } else {
        if (m_tmp.empty()) {
            m_tmp = temp_sibling(fs::path(m_target) / ("staging-" + m_name)).string();
            std::error_code ec;
            fs::create_directory(m_tmp, ec);
            if (ec)
                throw Error(
                    file_error(m_target, "cannot create a staging folder: " + ec.message()));
        }
        const std::string final_path = sequence_path(m_target, m_name, m_count, m_format);
        const std::string staged = (fs::path(m_tmp) / fs::path(final_path).filename()).string();
        try {
            write_image_file(staged, frame, pixel_format_of(m_format), m_opts.srgb_encode);
        } catch (const Error& e) {
            // Name the file the user asked for, not the staging one.
            std::string m = e.what();
            if (m.rfind(staged, 0) == 0) m = final_path + m.substr(staged.size());
            cancel();
            throw Error(m);
        }
        m_written.push_back(staged);
    }
    ++m_count;
}

std::vector<std::string> ClipWriter::finish() {
    if (m_done) return m_written;
    if (m_format == ClipFormat::Mp4) {
        if (!m_encoder) throw Error(file_error(m_target, "no frames to write"));
        const int status = m_encoder->wait();
        const std::string out = m_encoder->output();
        std::string why;
        std::error_code ec;
        if (status != 0 || out.find("Error writing trailer") != std::string::npos ||
            out.find("No space left") != std::string::npos)
            why = encoder_failure(*m_encoder, status);
        else if (!fs::exists(m_tmp) || fs::file_size(m_tmp, ec) == 0)
            why = "video encoder (ffmpeg) wrote nothing (the previous file is untouched)";
        else if (!mp4_has_moov(m_tmp))
            why =
                "video encoder (ffmpeg) wrote an incomplete file (no moov atom; disk full?); the "
                "previous file is untouched";
        if (why.empty()) {
            const int fd = ::open(m_tmp.c_str(), O_RDONLY);
            if (fd < 0 || ::fsync(fd) != 0)
                why = std::string("cannot sync the video to disk: ") + std::strerror(errno);
            if (fd >= 0) ::close(fd);
        }
        if (!why.empty()) {
            cancel();
            throw Error(file_error(m_target, why));
        }
        commit_temp(m_tmp, m_target);
        m_tmp.clear();
        m_encoder.reset();
        m_written = {m_target};
    } else if (!m_tmp.empty()) {
        std::vector<std::string> finals;
        for (int i = 0; i < m_count; ++i) {
            finals.push_back(sequence_path(m_target, m_name, i, m_format));
            commit_temp(m_written[i], finals.back());
        }
        // Frames of an earlier, longer export under the same name would mix with these.
        const std::string ext = "." + std::string(extension_of(pixel_format_of(m_format)));
        const std::regex old(
            "^" + std::regex_replace(m_name, std::regex(R"([.^$|()\[\]{}*+?\\])"), R"(\$&)") +
            "_(\\d{4,})" + std::regex_replace(ext, std::regex(R"(\.)"), R"(\.)") + "$");
        for (const auto& e : fs::directory_iterator(m_target)) {
            std::smatch m;
            const std::string fname = e.path().filename().string();
            if (std::regex_match(fname, m, old) && std::stol(m[1].str()) >= m_count) {
                std::error_code ec;
                fs::remove(e.path(), ec);
            }
        }
        std::error_code ec;
        fs::remove_all(m_tmp, ec);
        m_tmp.clear();
        m_written = finals;
    }
    m_done = true;
    return m_written;
}

void ClipWriter::cancel() {
    if (m_encoder) {
        m_encoder->kill();
        m_encoder.reset();
    }
    std::error_code ec;
    if (!m_tmp.empty()) fs::remove_all(m_tmp, ec);
    m_tmp.clear();
    m_written.clear();
    m_done = true;
}

}  // namespace refocus
