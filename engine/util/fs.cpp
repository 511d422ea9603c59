#include "util/fs.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

#include "util/error.h"

namespace refocus {

namespace {
std::string errno_text() { return std::strerror(errno); }

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

void commit_temp(const fs::path& tmp, const fs::path& path) {
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
        std::string why = errno_text();
        std::error_code ec;
        fs::remove(tmp, ec);
        throw Error(file_error(path.string(), "cannot replace file: " + why));
    }
    fsync_dir(path.parent_path());
}

void simulate_disk_full_after(long bytes) { g_fault_after = bytes; }

void write_file_atomic(const fs::path& path, const std::string& bytes) {
    fs::path tmp = temp_sibling(path);
    int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0) throw Error(file_error(path.string(), "cannot write: " + errno_text()));
    size_t done = 0;
    while (done < bytes.size()) {
        size_t chunk = bytes.size() - done;
        if (g_fault_after >= 0) chunk = std::min(chunk, size_t(std::max(0L, g_fault_after - long(done))));
        ssize_t n = chunk > 0 ? ::write(fd, bytes.data() + done, chunk) : (errno = ENOSPC, -1);
        if (n < 0) {
            if (errno == EINTR) continue;
            std::string why = errno_text();
            ::close(fd);
            ::unlink(tmp.c_str());
            throw Error(file_error(path.string(), "write failed: " + why +
                                                      " (the previous file is untouched)"));
        }
        done += static_cast<size_t>(n);
    }
    if (::fsync(fd) != 0 || ::close(fd) != 0) {
        std::string why = errno_text();
        ::unlink(tmp.c_str());
        throw Error(
            file_error(path.string(), "write failed: " + why + " (the previous file is untouched)"));
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

std::string format_pattern(const std::string& pattern, int index) {
    std::vector<char> buf(pattern.size() + 64);
    int n = std::snprintf(buf.data(), buf.size(), pattern.c_str(), index);
    if (n < 0 || static_cast<size_t>(n) >= buf.size())
        throw Error("bad file pattern '" + pattern + "'");
    return std::string(buf.data(), static_cast<size_t>(n));
}

}  // namespace refocus
