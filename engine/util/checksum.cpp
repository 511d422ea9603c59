#include "util/checksum.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <vector>

#include "util/error.h"

namespace refocus {

namespace {
constexpr uint64_t kMul = 0x9E3779B97F4A7C15ULL;
uint64_t mix(uint64_t h) {
    h ^= h >> 31;
    h *= 0xBF58476D1CE4E5B9ULL;
    return h ^ (h >> 29);
}
}  // namespace

uint64_t checksum64(const void* data, size_t n, uint64_t h) {
    const auto* p = static_cast<const unsigned char*>(data);
    h ^= 0x6A09E667F3BCC908ULL + n;
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        uint64_t w;
        std::memcpy(&w, p + i, 8);
        h = (h ^ mix(w * kMul)) * kMul;
    }
    uint64_t tail = 0;
    std::memcpy(&tail, p + i, n - i);
    h = (h ^ mix(tail * kMul + (n - i))) * kMul;
    return mix(h);
}

uint64_t file_checksum64(const fs::path& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f)
        throw Error(file_error(path.string(), std::string("cannot open: ") + std::strerror(errno)));
    std::vector<unsigned char> buf(1 << 20);
    uint64_t h = 0;
    size_t got;
    while ((got = std::fread(buf.data(), 1, buf.size(), f)) > 0) h = checksum64(buf.data(), got, h);
    const bool bad = std::ferror(f);
    std::fclose(f);
    if (bad) throw Error(file_error(path.string(), "cannot read"));
    return h;
}

std::string checksum_hex(uint64_t h) {
    char b[17];
    std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(h));
    return b;
}

}  // namespace refocus
