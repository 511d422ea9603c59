#include "project/project.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <functional>
#include <limits>
#include <mutex>
#include <thread>

#include "io/image_file.h"
#include "prepare/noise.h"
#include "util/error.h"
#include "util/json_file.h"

namespace refocus {

using nlohmann::json;

namespace {

// No side of a clip more than this many times the other: the masks' flow runs at 160 px wide or
// more, where the short side must keep 12 px (kMinClipSize).
constexpr int kMaxClipAspect = 12;

[[noreturn]] void field_error(const std::string& label, const std::string& field,
                              const std::string& problem) {
    json_field_error(label, field, problem);
}

// An integer value as long long; false when it does not fit (huge unsigned values).
bool as_int64(const json& v, long long& out) {
    if (v.is_number_unsigned()) {
        const auto u = v.get<unsigned long long>();
        if (u > static_cast<unsigned long long>(std::numeric_limits<long long>::max()))
            return false;
        out = static_cast<long long>(u);
        return true;
    }
    if (!v.is_number_integer()) return false;
    out = v.get<long long>();
    return true;
}

const json& require(const json& j, const std::string& label, const std::string& key,
                    json::value_t type, const std::string& path) {
    if (!j.contains(key)) field_error(label, path, "is missing");
    const json& v = j.at(key);
    bool ok = v.type() == type || (type == json::value_t::number_float && v.is_number()) ||
              (type == json::value_t::number_integer && v.is_number_integer());
    if (!ok)
        field_error(label, path,
                    std::string("must be ") +
                        (type == json::value_t::string           ? "a string"
                         : type == json::value_t::object         ? "an object"
                         : type == json::value_t::number_integer ? "an integer"
                                                                 : "a number") +
                        " (got " + json_brief(v) + ")");
    return v;
}

int positive_int(const json& j, const std::string& label, const std::string& key,
                 const std::string& path, int max) {
    const json& v = require(j, label, key, json::value_t::number_integer, path);
    long long x = 0;
    if (!as_int64(v, x) || x <= 0 || x > max)
        field_error(label, path,
                    "must be in 1.." + std::to_string(max) + " (got " + json_brief(v) + ")");
    return static_cast<int>(x);
}

// The "fit" section's budget and settings, checked where they enter (the fit reads them as they
// are). null minutes/iters (an unbounded budget once written as NaN/Inf) read as "not set".
void validate_fit_section(Project& p, const std::string& label) {
    if (!p.sections.contains("fit")) return;
    json& f = p.sections["fit"];
    if (!f.is_object()) field_error(label, "fit", "must be an object (got " + json_brief(f) + ")");
    for (const char* key : {"minutes", "iters"})
        if (f.contains(key) && f[key].is_null()) f[key] = 0;
    check_fit_section(f, label);
}

std::string bound_text(const FitFieldBound& b) {
    return std::string(b.integer ? "an integer" : "a number") + " in " +
           json_brief(b.integer ? json(static_cast<long long>(b.lo)) : json(b.lo)) + ".." +
           json_brief(b.integer ? json(static_cast<long long>(b.hi)) : json(b.hi));
}

}  // namespace

// One bound per stored number: the loader checks project.json with it and the CLI its flags,
// so that a value a flag stores always loads again.
const std::vector<FitFieldBound>& fit_field_bounds() {
    static const std::vector<FitFieldBound> bounds = {
        {"minutes", "--minutes", 0.0, kMaxFitMinutes, false},
        {"iters", "--iters", 0, double(kMaxFitIters), true},
        {"batch", "--batch", 0, double(kMaxFitBatch), true},  // 0: the model's choice
        {"seed", "--seed", 0, double(kMaxFitSeed), true},
    };
    return bounds;
}

const FitFieldBound& fit_field_bound(const std::string& key) {
    for (const auto& b : fit_field_bounds())
        if (key == b.key) return b;
    throw Error("internal: no bound for fit." + key);
}

void check_fit_section(const json& f, const std::string& label) {
    if (!f.is_object()) field_error(label, "fit", "must be an object (got " + json_brief(f) + ")");
    for (const auto& b : fit_field_bounds()) {
        if (!f.contains(b.key)) continue;
        const json& v = f[b.key];
        const std::string path = std::string("fit.") + b.key;
        const std::string why = std::string("must be ") + bound_text(b) + " (got " + json_brief(v) +
                                "; refocus fit " + b.flag + " sets it)";
        if (b.integer) {
            long long x = 0;
            if (!as_int64(v, x) || x < static_cast<long long>(b.lo) ||
                x > static_cast<long long>(b.hi))
                field_error(label, path, why);
        } else {
            if (!v.is_number()) field_error(label, path, why);
            const double x = v.get<double>();
            if (!(std::isfinite(x) && x >= b.lo && x <= b.hi)) field_error(label, path, why);
        }
    }
    for (const char* key : {"preset", "coc", "mask", "kernel", "checkpoint"})
        if (f.contains(key) && !f[key].is_string())
            field_error(label, std::string("fit.") + key,
                        "must be a string (got " + json_brief(f[key]) + ")");
}

long long checked_fit_flag(const std::string& key, const std::string& text) {
    const FitFieldBound& b = fit_field_bound(key);
    const std::string why =
        std::string(b.flag) + " must be " + bound_text(b) + " (got '" + text + "')";
    size_t used = 0;
    long long v = 0;
    try {
        v = std::stoll(text, &used);
    } catch (const std::exception&) {
        throw Error(why);
    }
    if (used != text.size() || v < static_cast<long long>(b.lo) || v > static_cast<long long>(b.hi))
        throw Error(why);
    return v;
}

fs::path Project::frame_path(int index) const {
    return dir / format_pattern(frame_pattern, index);
}

Image Project::read_frame(int index) const {
    if (index < 0 || index >= frames)
        throw Error(file_error(
            project_file().string(),
            "frame " + std::to_string(index) + " out of range 0.." + std::to_string(frames - 1)));
    ImageReadResult r =
        read_image_file(frame_path(index).string(), false, NonFinitePolicy::Reject, index);
    if (r.image.width != width || r.image.height != height)
        throw Error(file_error(frame_path(index).string(),
                               "cached frame size differs from the project's " +
                                   std::to_string(width) + "x" + std::to_string(height),
                               index));
    return to_rgb(r.image);
}

json Project::to_json() const {
    json j;
    j["version"] = version;
    j["name"] = name;
    j["source"] = {{"path", source}, {"kind", source_kind}, {"format", source_format}};
    j["clip"] = {{"width", width}, {"height", height}, {"frames", frames}, {"fps", fps}};
    j["cache"] = {{"frames", frame_pattern}};
    for (auto it = sections.begin(); it != sections.end(); ++it) j[it.key()] = it.value();
    return j;
}

Project Project::from_json(const json& j, const fs::path& dir, const std::string& label) {
    if (!j.is_object()) throw Error(file_error(label, "not a JSON object"));
    Project p;
    p.dir = dir;
    const json& jv = require(j, label, "version", json::value_t::number_integer, "version");
    long long version = 0;
    if (!as_int64(jv, version) || version > kVersion)
        throw Error(file_error(label, "written by a newer Refocus (project version " +
                                          json_brief(jv) + ", this build reads up to " +
                                          std::to_string(kVersion) +
                                          "); update Refocus to open it"));
    if (version < 1) field_error(label, "version", "must be >= 1 (got " + json_brief(jv) + ")");
    p.version = static_cast<int>(version);
    p.name = require(j, label, "name", json::value_t::string, "name").get<std::string>();
    const json& src = require(j, label, "source", json::value_t::object, "source");
    p.source = require(src, label, "path", json::value_t::string, "source.path").get<std::string>();
    p.source_kind =
        require(src, label, "kind", json::value_t::string, "source.kind").get<std::string>();
    if (p.source_kind != "video" && p.source_kind != "sequence")
        field_error(label, "source.kind",
                    "must be \"video\" or \"sequence\" (got \"" + p.source_kind + "\")");
    p.source_format = "uint8";
    if (src.contains("format"))
        p.source_format = require(src, label, "format", json::value_t::string, "source.format")
                              .get<std::string>();
    const json& clip = require(j, label, "clip", json::value_t::object, "clip");
    p.width = positive_int(clip, label, "width", "clip.width", 1 << 15);
    p.height = positive_int(clip, label, "height", "clip.height", 1 << 15);
    p.frames = positive_int(clip, label, "frames", "clip.frames", 1 << 20);
    p.fps = require(clip, label, "fps", json::value_t::number_float, "clip.fps").get<double>();
    if (!(p.fps > 0.0 && p.fps <= 1000.0))
        field_error(label, "clip.fps", "must be in (0, 1000] (got " + clip.at("fps").dump() + ")");
    const json& cache = require(j, label, "cache", json::value_t::object, "cache");
    p.frame_pattern =
        require(cache, label, "frames", json::value_t::string, "cache.frames").get<std::string>();
    if (fs::path(p.frame_pattern).is_absolute() || p.frame_pattern.find("..") != std::string::npos)
        field_error(label, "cache.frames",
                    "must be a path inside the project folder (got \"" + p.frame_pattern + "\")");
    if (const std::string why = frame_pattern_problem(p.frame_pattern); !why.empty())
        field_error(label, "cache.frames", "is not a frame pattern: " + why);
    // The cache is the frames/ folder: anything else (prep/'s radius maps) is not the clip.
    if (fs::path(p.frame_pattern).lexically_normal().parent_path() != "frames")
        field_error(
            label, "cache.frames",
            "must name files in the project's frames/ folder (got \"" + p.frame_pattern + "\")");
    if (p.frame_pattern.find('%') == std::string::npos)
        field_error(label, "cache.frames",
                    "must be a pattern with %d (got \"" + p.frame_pattern + "\")");
    for (auto it = j.begin(); it != j.end(); ++it) {
        static const char* known[] = {"version", "name", "source", "clip", "cache"};
        if (std::find(std::begin(known), std::end(known), it.key()) == std::end(known))
            p.sections[it.key()] = it.value();
    }
    validate_fit_section(p, label);
    if (p.sections.contains("noise")) NoiseEstimate::from_json(p.sections["noise"], label);
    return p;
}

Project Project::load(const fs::path& dir_or_file) {
    fs::path file = dir_or_file;
    const std::string what =
        " (a project is the folder 'refocus new <clip> -o <folder>' made, holding project.json)";
    if (fs::is_directory(file)) {
        file /= kFileName;
        // A long shot fitted as windows (session/windows.h): each window is the project.
        if (!fs::exists(file) && fs::exists(dir_or_file / "windows.json"))
            throw Error(file_error(
                dir_or_file.string(),
                "is a shot fitted as windows (windows.json); each window is a project of its own, "
                "in " +
                    (dir_or_file / "windows").string() +
                    " (refocus export stitches them; an atlas edit goes to one window)"));
        if (!fs::exists(file))
            throw Error(
                file_error(dir_or_file.string(),
                           "is not a project: no " + std::string(kFileName) + " in it" + what));
    } else if (fs::exists(file) && file.filename() != kFileName) {
        throw Error(file_error(file.string(), "is not a project" + what));
    }
    if (!fs::exists(file)) throw Error(file_error(file.string(), "no such project file"));
    const json j = read_json_file(file);
    Project p = from_json(j, file.parent_path(), file.string());
    for (int i : {0, p.frames - 1})
        if (!fs::exists(p.frame_path(i)))
            throw Error(file_error(p.frame_path(i).string(),
                                   "frame cache file is missing (" + file.string() + " lists " +
                                       std::to_string(p.frames) +
                                       " frames; re-create the project with 'refocus new')",
                                   i));
    return p;
}

void Project::save() const {
    write_file_atomic(project_file(), to_json().dump(2) + "\n");
}

void Project::save_merged(const std::vector<std::string>& own) {
    static std::mutex mutex;
    std::lock_guard<std::mutex> lock(mutex);
    if (fs::exists(project_file())) {
        try {
            const Project disk =
                from_json(read_json_file(project_file()), dir, project_file().string());
            for (auto it = disk.sections.begin(); it != disk.sections.end(); ++it)
                if (std::find(own.begin(), own.end(), it.key()) == own.end())
                    sections[it.key()] = it.value();
        } catch (const std::exception&) {
            // An unreadable project.json is replaced by this complete one.
        }
    }
    save();
}

bool is_project_path(const std::string& path) {
    fs::path p(path);
    if (fs::is_directory(p)) return fs::exists(p / Project::kFileName);
    return p.filename() == Project::kFileName;
}

namespace {

// Decodes on the calling thread and encodes the cache files on writer threads (an EXR frame
// takes longer to compress than to decode): at 1080p the ingest runs at the decoder's pace.
// The queue is bounded, so memory holds a few frames whatever the clip's length. The first
// error (decode or write) stops the ingest and is rethrown here. `progress(done, total)` is
// called on the calling thread.
void write_frames_threaded(ClipReader& reader, int first, int frames,
                           const std::function<void(int, const Image&)>& write,
                           const std::function<void(int, int)>& progress) {
    const int writers = std::clamp(static_cast<int>(std::thread::hardware_concurrency()), 1, 4);
    const size_t max_queued = static_cast<size_t>(writers) + 1;
    std::mutex m;
    std::condition_variable cv;
    std::deque<std::pair<int, Image>> queue;
    std::exception_ptr error;
    int written = 0;
    bool closed = false;
    auto worker = [&] {
        while (true) {
            std::pair<int, Image> job;
            {
                std::unique_lock<std::mutex> lk(m);
                cv.wait(lk, [&] { return !queue.empty() || closed || error; });
                if (error || queue.empty()) return;
                job = std::move(queue.front());
                queue.pop_front();
            }
            cv.notify_all();
            try {
                write(job.first, job.second);
            } catch (...) {
                std::lock_guard<std::mutex> lk(m);
                if (!error) error = std::current_exception();
            }
            {
                std::lock_guard<std::mutex> lk(m);
                ++written;
            }
            cv.notify_all();
        }
    };
    std::vector<std::thread> pool;
    for (int k = 0; k < writers; ++k) pool.emplace_back(worker);
    auto finish = [&] {
        {
            std::lock_guard<std::mutex> lk(m);
            closed = true;
        }
        cv.notify_all();
        for (auto& t : pool) t.join();
    };
    int reported = 0;
    auto report = [&](bool all) {
        std::unique_lock<std::mutex> lk(m);
        if (all) cv.wait(lk, [&] { return written == frames || error; });
        const int done = written;
        lk.unlock();
        if (progress)
            for (; reported < done;) progress(++reported, frames);
    };
    try {
        for (int i = 0; i < frames; ++i) {
            Image f = reader.read(first + i);
            {
                std::unique_lock<std::mutex> lk(m);
                cv.wait(lk, [&] { return queue.size() < max_queued || error; });
                if (error) break;
                queue.emplace_back(i, std::move(f));
            }
            cv.notify_all();
            report(false);  // may throw (an interrupt): the writers are joined below
        }
        report(true);
    } catch (...) {
        {
            std::lock_guard<std::mutex> lk(m);
            if (!error) error = std::current_exception();
        }
        finish();
        std::rethrow_exception(error);
    }
    finish();
    if (error) std::rethrow_exception(error);
}

}  // namespace

Project create_project(const std::string& clip, const fs::path& dir, const ClipReadOptions& opts,
                       const std::function<void(int, int)>& progress) {
    if (fs::exists(dir / Project::kFileName))
        throw Error(file_error((dir / Project::kFileName).string(),
                               "a project already exists here; choose another folder"));
    if (fs::exists(dir) && !fs::is_directory(dir))
        throw Error(file_error(dir.string(), "exists and is not a folder"));
    auto reader = ClipReader::open(clip, opts);
    const ClipInfo& info = reader->info();
    if (!info.note.empty()) std::fprintf(stderr, "note: %s: %s\n", clip.c_str(), info.note.c_str());
    if (info.width < kMinClipSize || info.height < kMinClipSize)
        throw Error(file_error(
            clip, "the clip is " + std::to_string(info.width) + "x" + std::to_string(info.height) +
                      ": too small, Refocus needs at least " + std::to_string(kMinClipSize) + "x" +
                      std::to_string(kMinClipSize) + " pixels (optical flow)"));
    // Flow and masks work on frames scaled to a few hundred px wide; a clip much wider than
    // high (or higher than wide) would leave them under 12 px.
    if (std::max(info.width, info.height) > kMaxClipAspect * std::min(info.width, info.height))
        throw Error(file_error(clip, "the clip is " + std::to_string(info.width) + "x" +
                                         std::to_string(info.height) + ": more than " +
                                         std::to_string(kMaxClipAspect) +
                                         " times as wide as high (or high as wide); Refocus "
                                         "needs a frame no narrower than 1:" +
                                         std::to_string(kMaxClipAspect) + " (crop it first)"));

    Project p;
    p.dir = dir;
    p.name = fs::path(clip).stem().string();
    if (p.name.empty() || p.name.find('%') != std::string::npos) p.name = dir.filename().string();
    // Store the source relative to the project when that is possible.
    fs::path abs_clip = fs::absolute(clip).lexically_normal();
    fs::path rel = abs_clip.lexically_relative(fs::absolute(dir).lexically_normal());
    p.source = rel.empty() ? abs_clip.string() : rel.string();
    p.source_kind = info.kind;
    p.source_format = info.source_format;
    p.width = info.width;
    p.height = info.height;
    // A range of the clip (a window of a long shot): its frames become frames 0.. here.
    const int first = opts.first, last = opts.last < 0 ? info.frames - 1 : opts.last;
    if (first < 0 || first > last || last >= info.frames)
        throw Error(file_error(clip, "frames " + std::to_string(first) + ".." +
                                         std::to_string(last) + " are not inside the clip's 0.." +
                                         std::to_string(info.frames - 1)));
    p.frames = last - first + 1;
    if (p.frames != info.frames) p.sections["source_range"] = {{"first", first}, {"last", last}};
    p.fps = info.fps;
    p.frame_pattern = "frames/frame_%04d.exr";
    // Built in a temporary folder and moved into place complete (project.json last): a failed
    // or interrupted ingest leaves no partial project.
    const fs::path tmp = make_temp_dir_beside(fs::absolute(dir).lexically_normal());
    try {
        // The noise is measured on the ingested frames (before the cache's half precision).
        const std::vector<int> sample = noise_sample_frames(p.frames);
        const double rounding = source_rounding_var(info.source_format);
        std::vector<std::array<double, 3>> noise(sample.size(), {{-1, -1, -1}});
        Project staged = p;  // holds source_range
        staged.dir = tmp;
        std::error_code ec;
        fs::create_directories(tmp / "frames", ec);
        if (ec)
            throw Error(file_error(dir.string(), "cannot create project folder: " + ec.message()));
        // Float sources keep float precision; 8/16-bit sources fit in half exactly enough.
        const PixelFormat cache_format =
            info.source_format == "float" ? PixelFormat::ExrFloat : PixelFormat::ExrHalf;
        write_frames_threaded(
            *reader, first, p.frames,
            [&](int i, const Image& f) {
                const auto at = std::find(sample.begin(), sample.end(), i);
                if (at != sample.end())  // each frame written by one thread: its own slot
                    noise[size_t(at - sample.begin())] = frame_noise_levels(f, rounding);
                try {
                    write_image_file(staged.frame_path(i).string(), f, cache_format, false, "piz");
                } catch (const Error& e) {
                    std::string m = e.what();
                    const std::string from = staged.frame_path(i).string();
                    if (m.rfind(from, 0) == 0) m = p.frame_path(i).string() + m.substr(from.size());
                    throw Error(m);
                }
            },
            progress);
        const NoiseEstimate n = combine_frame_noise(noise);
        if (n.measured()) staged.sections["noise"] = n.to_json();
        p.sections = staged.sections;
        staged.save();
        publish_dir(tmp, dir, {Project::kFileName});
    } catch (...) {
        std::error_code ec;
        fs::remove_all(tmp, ec);
        throw;
    }
    return p;
}

}  // namespace refocus
