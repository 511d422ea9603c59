#include "util/lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <map>
#include <mutex>

#include "util/error.h"

namespace refocus {

namespace {
struct Held {
    int fd = -1;
    int count = 0;
};
std::mutex g_mutex;
std::map<std::string, Held> g_held;

std::string key_of(const fs::path& dir) {
    std::error_code ec;
    fs::path c = fs::weakly_canonical(dir, ec);
    return (ec ? fs::absolute(dir) : c).string();
}

std::string read_holder(int fd) {
    char buf[512];
    const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
    std::string s(buf, n > 0 ? size_t(n) : 0);
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    for (char& c : s)
        if (c == '\n') c = ' ';
    return s;
}
}  // namespace

std::unique_ptr<ProjectLock> ProjectLock::acquire(const fs::path& dir_given,
                                                  const std::string& what) {
    const fs::path project_dir = dir_given.empty() ? fs::path(".") : dir_given;
    const std::string key = key_of(project_dir);
    std::lock_guard<std::mutex> guard(g_mutex);
    auto it = g_held.find(key);
    if (it != g_held.end()) {
        ++it->second.count;
        return std::unique_ptr<ProjectLock>(new ProjectLock(key));
    }
    const fs::path file = file_of(project_dir);
    const int fd = ::open(file.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0)
        throw Error(file_error(
            file.string(), std::string("cannot create the project lock: ") + std::strerror(errno)));
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        const int err = errno;
        std::string who = read_holder(fd);
        ::close(fd);
        if (err == EWOULDBLOCK)
            throw Error(file_error(project_dir.string(),
                                   "the project is in use by another writer (" +
                                       (who.empty() ? std::string("unknown process") : who) +
                                       "); wait for it to finish or stop it"));
        throw Error(file_error(file.string(),
                               std::string("cannot lock the project: ") + std::strerror(err)));
    }
    // The previous holder (if any) is dead: its line is replaced by ours.
    const std::string line = "pid " + std::to_string(::getpid()) + ": " + what + "\n";
    if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, line.data(), line.size(), 0) < 0) {
        // The lock itself holds; only the holder's description is missing.
    }
    g_held[key] = Held{fd, 1};
    return std::unique_ptr<ProjectLock>(new ProjectLock(key));
}

std::string ProjectLock::holder(const fs::path& project_dir) {
    const fs::path file = file_of(project_dir);
    const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return "";
    std::string who;
    if (::flock(fd, LOCK_SH | LOCK_NB) != 0)
        who = read_holder(fd);
    else
        ::flock(fd, LOCK_UN);
    ::close(fd);
    return who;
}

ProjectLock::~ProjectLock() {
    std::lock_guard<std::mutex> guard(g_mutex);
    auto it = g_held.find(m_key);
    if (it == g_held.end() || --it->second.count > 0) return;
    // Empty the holder line first so that a reader never sees a stale name.
    if (::ftruncate(it->second.fd, 0) != 0) {
    }
    ::flock(it->second.fd, LOCK_UN);
    ::close(it->second.fd);
    g_held.erase(it);
}

}  // namespace refocus
