#include "util/fs.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <cstdlib>
#include <fstream>
#include <regex>
#include <sstream>
#include <vector>

#include "util/error.h"

namespace refocus {

namespace {
std::string errno_text() {
    return std::strerror(errno);
}

long g_fault_after = -1;

void fsync_dir(const fs::path& dir) {
    int fd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY);
    if (fd >= 0) {
        ::fsync(fd);
        ::close(fd);
    }
}
}  // namespace

fs::path temp_sibling(const fs::path& path) {
    static std::atomic<int> counter{0};
    fs::path dir = path.parent_path();
    std::string name = "." + path.stem().string() + ".tmp-" + std::to_string(::getpid()) + "-" +
                       std::to_string(counter++) + path.extension().string();
    return dir / name;
}

void remove_stale_temporaries(const fs::path& dir) {
    static const std::regex name(R"(^\..*\.tmp-(\d+)-\d+.*$)");
    std::error_code ec;
    for (fs::directory_iterator it(dir.empty() ? "." : dir, ec), end; !ec && it != end;
         it.increment(ec)) {
        std::smatch m;
        const std::string n = it->path().filename().string();
        if (!std::regex_match(n, m, name)) continue;
        const long pid = std::strtol(m[1].str().c_str(), nullptr, 10);
        if (pid <= 0 || pid == ::getpid()) continue;
        if (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH) continue;  // still running
        std::error_code rm;
        fs::remove_all(it->path(), rm);
    }
}

void commit_temp(const fs::path& tmp, const fs::path& path) {
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
        std::string why = errno_text();
        std::error_code ec;
        fs::remove(tmp, ec);
        throw Error(file_error(path.string(), "cannot replace file: " + why));
    }
    fsync_dir(path.parent_path());
}

fs::path make_temp_dir_beside(const fs::path& dir) {
    fs::path target = dir.filename().empty() ? dir.parent_path() : dir;
    const fs::path parent = target.parent_path();
    std::error_code ec;
    if (!parent.empty()) fs::create_directories(parent, ec);
    remove_stale_temporaries(parent);
    for (int attempt = 0; attempt < 100; ++attempt) {
        const fs::path tmp = temp_sibling(target);
        if (::mkdir(tmp.c_str(), 0755) == 0) return tmp;
        if (errno != EEXIST)
            throw Error(file_error(target.string(),
                                   "cannot create a temporary folder beside it: " + errno_text()));
    }
    throw Error(file_error(target.string(), "cannot create a temporary folder beside it"));
}

namespace {
void move_entries(const fs::path& from, const fs::path& to, const std::vector<std::string>& last) {
    std::vector<fs::path> entries;
    for (const auto& e : fs::directory_iterator(from)) entries.push_back(e.path());
    std::stable_partition(entries.begin(), entries.end(), [&](const fs::path& p) {
        return std::find(last.begin(), last.end(), p.filename().string()) == last.end();
    });
    for (const auto& src : entries) {
        const fs::path dst = to / src.filename();
        std::error_code ec;
        if (fs::is_directory(src) && fs::is_directory(dst) && !fs::is_empty(dst, ec)) {
            move_entries(src, dst, last);
            continue;
        }
        if (fs::is_directory(dst)) fs::remove(dst, ec);  // empty
        if (::rename(src.c_str(), dst.c_str()) != 0)
            throw Error(file_error(dst.string(), "cannot move into place: " + errno_text()));
    }
}
}  // namespace

void publish_dir(const fs::path& tmp, const fs::path& dest, const std::vector<std::string>& last) {
    std::error_code ec;
    try {
        if (!fs::exists(dest) || (fs::is_directory(dest) && fs::is_empty(dest, ec))) {
            if (::rename(tmp.c_str(), dest.c_str()) != 0)
                throw Error(file_error(dest.string(), "cannot move into place: " + errno_text()));
        } else {
            if (!fs::is_directory(dest))
                throw Error(file_error(dest.string(), "exists and is not a folder"));
            move_entries(tmp, dest, last);
            fs::remove_all(tmp, ec);
        }
    } catch (...) {
        fs::remove_all(tmp, ec);
        throw;
    }
    fsync_dir(dest.parent_path());
}

void simulate_disk_full_after(long bytes) {
    g_fault_after = bytes;
}

void write_file_atomic(const fs::path& path, const std::string& bytes) {
    fs::path tmp = temp_sibling(path);
    int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0) throw Error(file_error(path.string(), "cannot write: " + errno_text()));
    size_t done = 0;
    while (done < bytes.size()) {
        size_t chunk = bytes.size() - done;
        if (g_fault_after >= 0)
            chunk = std::min(chunk, size_t(std::max(0L, g_fault_after - long(done))));
        ssize_t n = chunk > 0 ? ::write(fd, bytes.data() + done, chunk) : (errno = ENOSPC, -1);
        if (n < 0) {
            if (errno == EINTR) continue;
            std::string why = errno_text();
            ::close(fd);
            ::unlink(tmp.c_str());
            throw Error(file_error(path.string(),
                                   "write failed: " + why + " (the previous file is untouched)"));
        }
        done += static_cast<size_t>(n);
    }
    if (::fsync(fd) != 0 || ::close(fd) != 0) {
        std::string why = errno_text();
        ::unlink(tmp.c_str());
        throw Error(file_error(path.string(),
                               "write failed: " + why + " (the previous file is untouched)"));
    }
    commit_temp(tmp, path);
}

std::string read_text_file(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(file_error(path.string(), "cannot open: " + errno_text()));
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

namespace {
constexpr int kMaxPatternWidth = 10;

// Fills `out` and returns "" or the problem.
std::string parse_pattern(const std::string& pattern, FramePattern& out) {
    out = FramePattern{};
    bool seen = false;
    std::string* cur = &out.prefix;
    for (size_t i = 0; i < pattern.size(); ++i) {
        const char c = pattern[i];
        if (c == '\0') return "contains a NUL character";
        if (c != '%') {
            *cur += c;
            continue;
        }
        if (i + 1 < pattern.size() && pattern[i + 1] == '%') {
            *cur += '%';
            ++i;
            continue;
        }
        size_t j = i + 1;
        std::string digits;
        while (j < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[j])))
            digits += pattern[j++];
        if (j >= pattern.size() || pattern[j] != 'd')
            return "'" + pattern.substr(i, std::min<size_t>(j - i + 1, 8)) +
                   "' is not allowed (use one %d or %0Nd; write %% for a literal percent)";
        if (!digits.empty() &&
            (digits[0] != '0' || digits.size() > 3 || std::stoi(digits) > kMaxPatternWidth))
            return "'%" + digits + "d': the width must be written %0Nd with N at most " +
                   std::to_string(kMaxPatternWidth);
        if (seen) return "more than one frame number (use exactly one %d or %0Nd)";
        seen = true;
        out.width = digits.empty() ? 0 : std::stoi(digits);
        cur = &out.suffix;
        i = j;
    }
    if (!seen) return "needs one %d or %0Nd for the frame number";
    return "";
}
}  // namespace

std::string FramePattern::format(long index) const {
    std::string n = std::to_string(index < 0 ? -index : index);
    if (static_cast<int>(n.size()) < width) n.insert(0, width - n.size(), '0');
    return prefix + (index < 0 ? "-" : "") + n + suffix;
}

FramePattern parse_frame_pattern(const std::string& pattern, const std::string& label) {
    FramePattern p;
    std::string why = parse_pattern(pattern, p);
    if (!why.empty()) {
        std::string msg = "bad frame pattern '" + pattern + "': " + why;
        throw Error(label.empty() ? msg : file_error(label, msg));
    }
    return p;
}

std::string frame_pattern_problem(const std::string& pattern) {
    FramePattern p;
    return parse_pattern(pattern, p);
}

std::string format_pattern(const std::string& pattern, int index) {
    return parse_frame_pattern(pattern).format(index);
}

}  // namespace refocus
