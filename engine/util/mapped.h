#pragma once
// Clip-sized arrays in file mappings. A long or large clip's per-frame arrays (its frames, radius
// maps, masks, flow) are allocated in an unlinked file instead of anonymous memory: the kernel
// writes them out and reads them back as pages are used, so the process holds only the frames
// it is working on. A trimmer thread drops every mapping's pages from the process every
// `trim_ms` (madvise MADV_DONTNEED on a shared file mapping keeps the data in the file and the
// page cache; the next access maps it back). The page cache keeps what the machine has room for.
#include <torch/types.h>

#include <cstdint>

#include "util/fs.h"

namespace refocus {

// A zero-filled float32 tensor of `shape` stored in an unlinked file in `dir` (created if
// absent). Throws refocus::Error naming the folder when the file cannot be made or mapped.
torch::Tensor mapped_tensor(at::IntArrayRef shape, const fs::path& dir);

// A float32 tensor of `shape` in the named file `file`: `create` makes (or truncates) it, zero
// filled and writable; otherwise the file must hold exactly the shape's bytes and is mapped
// read-only (writing into the tensor faults). Throws refocus::Error naming the file.
torch::Tensor mapped_file_tensor(const fs::path& file, at::IntArrayRef shape, bool create);

// Whether `t`'s storage is one of mapped_tensor's or mapped_file_tensor's.
bool is_mapped(const torch::Tensor& t);

// Drops the pages of every live mapping from this process (the data stays). Safe at any time.
void trim_mapped();

// Starts (once) the thread that calls trim_mapped every `period_ms` while mappings exist.
void start_mapped_trimmer(int period_ms = 500);

// Bytes held in live mappings (for logs and tests).
int64_t mapped_bytes();

}  // namespace refocus
