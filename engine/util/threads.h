#pragma once
#include <string>

namespace refocus {
// Sets LibTorch's intra-op threads (it starts at 1 here), OpenMP's and OpenCV's to the core
// count (or REFOCUS_THREADS). Call once at program start, before any tensor work.
int init_threads();
// The thread count REFOCUS_THREADS asks for: a whole number in 1..4 × `cores`; anything else
// (unset aside) sets `warning` and gives `cores`.
int threads_from_env(const char* env, int cores, std::string* warning);
}  // namespace refocus
