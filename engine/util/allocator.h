#pragma once

namespace refocus {
// Keeps glibc's malloc from handing frame-sized blocks back to the kernel at every free: a
// step allocates and frees the same tensors each time, and with blocks over malloc's adaptive
// mmap threshold each one was mapped, page-faulted in and unmapped again (docs/benchmarks.md,
// Speed: system time half of it). Call once at program start, before any tensor work.
void tune_allocator();
}  // namespace refocus
