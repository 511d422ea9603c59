#pragma once
// Errors at the boundary: the engine throws refocus::Error with a message that names the file
// (and frame) and the problem; main() prints it on one line and exits non-zero.
#include <stdexcept>
#include <string>

namespace refocus {

class Error : public std::runtime_error {
  public:
    explicit Error(const std::string& what) : std::runtime_error(what) {}
};

// "path: problem" or "path (frame N): problem".
std::string file_error(const std::string& path, const std::string& problem, int frame = -1);

}  // namespace refocus
