#include "util/mapped.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <map>
#include <mutex>
#include <thread>

#include <torch/torch.h>

#include "util/error.h"

namespace refocus {

namespace {

// Never destroyed: the trimmer thread may outlive static destruction at exit.
std::mutex& g_mutex = *new std::mutex;
std::map<void*, size_t>& g_maps = *new std::map<void*, size_t>;  // live mappings: base → bytes

int open_unlinked(const fs::path& dir) {
#ifdef O_TMPFILE
    int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd >= 0) return fd;
#endif
    // File systems without O_TMPFILE: a named file, unlinked at once.
    std::string name = (dir / ".refocus-map-XXXXXX").string();
    int fd2 = ::mkstemp(name.data());
    if (fd2 >= 0) ::unlink(name.c_str());
    return fd2;
}

}  // namespace

namespace {

size_t float_bytes(at::IntArrayRef shape) {
    int64_t n = 1;
    for (int64_t s : shape) {
        if (s < 0) throw Error("mapped_tensor: negative size");
        n *= s;
    }
    return size_t(std::max<int64_t>(n, 1)) * sizeof(float);
}

// Reserves the file's blocks: a mapping written past a full disk faults (SIGBUS) where this says
// so at once. File systems without fallocate keep the sparse file.
int reserve(int fd, size_t bytes) {
    if (::ftruncate(fd, off_t(bytes)) != 0) return errno;
    if (::fallocate(fd, 0, 0, off_t(bytes)) != 0 && errno != EOPNOTSUPP && errno != ENOSYS)
        return errno;
    return 0;
}

// Maps `bytes` of `fd` (closed here: the mapping keeps the file) as a tracked tensor.
torch::Tensor map_fd(int fd, size_t bytes, bool writable, at::IntArrayRef shape,
                     const std::string& where) {
    void* p =
        ::mmap(nullptr, bytes, writable ? PROT_READ | PROT_WRITE : PROT_READ, MAP_SHARED, fd, 0);
    const int e = errno;
    ::close(fd);
    if (p == MAP_FAILED)
        throw Error(
            file_error(where, std::string("cannot map a working file: ") + std::strerror(e)));
    {
        std::lock_guard<std::mutex> lock(g_mutex);
        g_maps[p] = bytes;
    }
    auto release = [bytes](void* q) {
        {
            std::lock_guard<std::mutex> lock(g_mutex);
            g_maps.erase(q);
        }
        ::munmap(q, bytes);
    };
    return torch::from_blob(p, shape, release, torch::kFloat32);
}

}  // namespace

torch::Tensor mapped_tensor(at::IntArrayRef shape, const fs::path& dir) {
    const size_t bytes = float_bytes(shape);
    std::error_code ec;
    fs::create_directories(dir, ec);
    const int fd = open_unlinked(dir);
    if (fd < 0)
        throw Error(file_error(dir.string(),
                               std::string("cannot make a working file: ") + std::strerror(errno)));
    if (const int e = reserve(fd, bytes)) {
        ::close(fd);
        throw Error(file_error(dir.string(), "cannot size a working file of " +
                                                 std::to_string(bytes >> 20) +
                                                 " MB: " + std::strerror(e)));
    }
    return map_fd(fd, bytes, true, shape, dir.string());
}

torch::Tensor mapped_file_tensor(const fs::path& file, at::IntArrayRef shape, bool create) {
    const size_t bytes = float_bytes(shape);
    const int fd = create ? ::open(file.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644)
                          : ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        throw Error(file_error(file.string(), std::string("cannot open: ") + std::strerror(errno)));
    if (const int e = create ? reserve(fd, bytes) : 0) {
        ::close(fd);
        ::unlink(file.c_str());
        throw Error(file_error(file.string(), "cannot size it to " + std::to_string(bytes >> 20) +
                                                  " MB: " + std::strerror(e)));
    }
    if (!create) {
        const off_t end = ::lseek(fd, 0, SEEK_END);
        if (end != off_t(bytes)) {
            ::close(fd);
            throw Error(file_error(file.string(), "holds " + std::to_string(int64_t(end)) +
                                                      " bytes, not the " + std::to_string(bytes) +
                                                      " its shape takes"));
        }
    }
    return map_fd(fd, bytes, create, shape, file.string());
}

bool is_mapped(const torch::Tensor& t) {
    if (!t.defined() || !t.has_storage()) return false;
    void* base = t.storage().data_ptr().get();
    std::lock_guard<std::mutex> lock(g_mutex);
    return g_maps.count(base) > 0;
}

void trim_mapped() {
    std::lock_guard<std::mutex> lock(g_mutex);  // a mapping cannot go while it is trimmed
    for (const auto& [p, bytes] : g_maps) ::madvise(p, bytes, MADV_DONTNEED);
}

int64_t mapped_bytes() {
    std::lock_guard<std::mutex> lock(g_mutex);
    int64_t s = 0;
    for (const auto& m : g_maps) s += int64_t(m.second);
    return s;
}

void start_mapped_trimmer(int period_ms) {
    static std::once_flag once;
    std::call_once(once, [period_ms] {
        std::thread([period_ms] {
            for (;;) {
                std::this_thread::sleep_for(std::chrono::milliseconds(period_ms));
                trim_mapped();
            }
        }).detach();
    });
}

}  // namespace refocus
