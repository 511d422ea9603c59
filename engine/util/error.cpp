#include "util/error.h"

namespace refocus {

std::string file_error(const std::string& path, const std::string& problem, int frame) {
    std::string s = path;
    if (frame >= 0) s += " (frame " + std::to_string(frame) + ")";
    return s + ": " + problem;
}

}  // namespace refocus
