#pragma once
#include <cstdint>
#include <functional>
#include <string>

namespace refocus {
// Sets LibTorch's intra-op threads (it starts at 1 here), OpenMP's and OpenCV's to the core
// count (or REFOCUS_THREADS). Call once at program start, before any tensor work.
int init_threads();
// The thread count REFOCUS_THREADS asks for: a whole number in 1..4 × `cores`; anything else
// (unset aside) sets `warning` and gives `cores`.
int threads_from_env(const char* env, int cores, std::string* warning);
// Runs fn(i, k) for every i in [0, n) on `threads` threads (k = 0 .. threads − 1; thread k takes
// i ≡ k mod threads), for per-frame work that is serial inside (an image file's encoding, an
// optical flow with its own estimator). The first exception is rethrown once all have stopped.
// threads ≤ 0: LibTorch's thread count (init_threads).
void for_each_on_threads(int n, int threads, const std::function<void(int i, int k)>& fn);
// Runs fn(i, p) for every i in [0, n), part p taking i ≡ p mod `parts`, each part on one of
// LibTorch's threads (at::parallel_for) with the caller's grad mode: sums kept per part and
// added in part order are the same whatever the thread count (LibTorch's CPU sampler runs one
// image on one thread, so frames summed this way use the cores).
void for_each_in_parts(int64_t n, int parts, const std::function<void(int64_t i, int p)>& fn);
}  // namespace refocus
