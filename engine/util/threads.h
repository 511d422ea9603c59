#pragma once
namespace refocus {
// Sets LibTorch's intra-op threads (it starts at 1 here), OpenMP's and OpenCV's to the core
// count (or REFOCUS_THREADS). Call once at program start, before any tensor work.
int init_threads();
}  // namespace refocus
