#pragma once
// Clips: a video file (mp4, mov, mkv, avi, ... through OpenCV's FFmpeg backend) or an image
// sequence (a folder, or a printf pattern such as shot/frame_%04d.exr) through OpenImageIO.
// Frames come out as linear-light float RGB of one size.
#include <memory>
#include <string>
#include <vector>

#include "io/image.h"
#include "io/image_file.h"
#include "util/process.h"

namespace refocus {

struct ClipInfo {
    std::string path;  // as given
    std::string kind;  // "video" or "sequence"
    int width = 0;
    int height = 0;
    int frames = 0;
    double fps = 0.0;
    double stream_fps = 0.0;         // a video's own rate (fps differs where --fps overrides it)
    int source_channels = 0;         // channels stored in the source
    std::string source_format;       // "uint8", "uint16", "half", "float"
    bool source_linear = false;      // true when the source stores linear light (EXR, float)
    std::vector<std::string> files;  // a sequence's frame files, in order
    std::string note;                // what the reader assumed that the user should know
};

struct ClipReadOptions {
    NonFinitePolicy nonfinite = NonFinitePolicy::Reject;
    double default_fps = 24.0;  // image sequences carry no rate
    bool fps_override = false;  // default_fps also replaces a video's own rate (new --fps)
    int first = 0, last = -1;   // create_project: ingest frames first..last (-1: to the end)
};

// A video file by its extension. A file that exists is never read as a frame pattern,
// whatever '%' its name holds ("100%.mp4").
bool is_video_path(const std::string& path);

// Does the mp4/mov file at `path` hold a top-level "moov" atom (a complete, playable file)?
bool mp4_has_moov(const std::string& path);

class ClipReader {
  public:
    // Opens and validates the clip: size and frame count are known after this. A video is
    // decoded once here to count its frames (containers' counts are estimates); a sequence's
    // files are all listed and their headers checked for one size and a supported layout.
    static std::unique_ptr<ClipReader> open(const std::string& path,
                                            const ClipReadOptions& opts = {});
    virtual ~ClipReader() = default;
    const ClipInfo& info() const { return m_info; }
    // Frame `index` in [0, frames) as linear RGB. Sequential reads are fastest.
    virtual Image read(int index) = 0;

  protected:
    ClipInfo m_info;
};

// Reads every frame (small clips, tests).
std::vector<Image> read_all_frames(const std::string& path, const ClipReadOptions& opts = {},
                                   ClipInfo* info = nullptr);

// Output of a clip: a sequence `<dir>/<name>_%04d.<ext>` counted from 0, or an H.264 mp4.
enum class ClipFormat { Png8, Png16, Tiff16, ExrHalf, ExrFloat, Mp4 };
ClipFormat parse_clip_format(const std::string& name);  // png, png16, tiff, exr, exr32, mp4

struct ClipWriteOptions {
    double fps = 24.0;
    int crf = 14;             // x264 constant rate factor for mp4 (lower = better)
    bool srgb_encode = true;  // false for data passes in integer formats
};

// Writes frames one at a time. Sequence frames go to a hidden staging folder inside the target
// and are renamed into place by finish() (frames of an older, longer export with the same name
// are removed then, so a folder never mixes two exports); an mp4 is encoded by ffmpeg (spawned
// without a shell) into a temporary file, checked (exit status, trailer errors, a moov atom)
// and renamed into place by finish(). A writer destroyed before finish() removes what it
// wrote, so an output is complete or absent and a failed export keeps the previous one.
class ClipWriter {
  public:
    // `target` is the output folder for sequences, the .mp4 file for mp4.
    ClipWriter(const std::string& target, const std::string& name, ClipFormat format,
               const ClipWriteOptions& opts = {});
    ~ClipWriter();
    ClipWriter(const ClipWriter&) = delete;
    ClipWriter& operator=(const ClipWriter&) = delete;

    void write(const Image& frame);
    std::vector<std::string> finish();  // the files written
    void cancel();
    int frames_written() const { return m_count; }

    static std::string sequence_path(const std::string& dir, const std::string& name, int index,
                                     ClipFormat format);

  private:
    void open_encoder(int w, int h);
    std::string m_target, m_name;
    ClipFormat m_format;
    ClipWriteOptions m_opts;
    int m_count = 0;
    int m_width = 0, m_height = 0;
    std::vector<std::string> m_written;  // sequences: staged files
    std::string m_tmp;                   // mp4 temporary / sequence staging folder
    std::unique_ptr<Subprocess> m_encoder;
    bool m_done = false;
};

}  // namespace refocus
