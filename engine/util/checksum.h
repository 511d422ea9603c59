#pragma once
// A fast 64-bit checksum (word-at-a-time multiply-xorshift) for detecting damaged files: not a
// cryptographic hash, only a check that the bytes are the ones written.
#include <cstddef>
#include <cstdint>
#include <string>

#include "util/fs.h"

namespace refocus {

// Checksum of `n` bytes, continuing from `h` (0 starts a new one).
uint64_t checksum64(const void* data, size_t n, uint64_t h = 0);
// Of a whole file, read in chunks; refocus::Error naming the file when it cannot be read.
uint64_t file_checksum64(const fs::path& path);
// 16 lowercase hex digits.
std::string checksum_hex(uint64_t h);

}  // namespace refocus
