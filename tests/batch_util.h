#pragma once
// Files as bytes, for the batch suites (test_batch, test_batch_slurm): outputs compared byte for
// byte, shot lists written.
#include <fstream>
#include <iterator>
#include <string>

#include "util/fs.h"

namespace refocus::test {

inline std::string bytes_of(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(f), {});
}

inline void write(const fs::path& p, const std::string& text) {
    std::ofstream f(p);
    f << text;
}

}  // namespace refocus::test
