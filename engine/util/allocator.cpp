#include "util/allocator.h"

#include <cstddef>  // defines __GLIBC__ where it is glibc

#ifdef __GLIBC__
#include <malloc.h>
#endif

namespace refocus {

void tune_allocator() {
#ifdef __GLIBC__
    // Blocks up to 256 MiB (a 1080p batch of four RGB frames is 100 MiB) come from the heap and
    // are reused; the heap's top is returned only past 256 MiB free. Setting either one turns
    // off malloc's own threshold, which starts at 128 KiB: both are set. What a long clip frees
    // at once (its proxies after the set-up) still goes back by malloc_trim.
    constexpr int kMiB = 1 << 20;
    mallopt(M_MMAP_THRESHOLD, 256 * kMiB);
    mallopt(M_TRIM_THRESHOLD, 256 * kMiB);
#endif
}

}  // namespace refocus
