#pragma once
#include <filesystem>
#include <string>

namespace refocus {

namespace fs = std::filesystem;

// Writes `bytes` to `path` atomically: a temporary file in the same folder, fsync, rename,
// fsync of the folder. On any failure (full disk, no permission) the temporary is removed, the
// previous file at `path` is left untouched and refocus::Error names the file and the cause.
void write_file_atomic(const fs::path& path, const std::string& bytes);

// A temporary sibling name for `path` ("<dir>/.<name>.tmp-<pid>-<n><ext>"), keeping the
// extension so that format writers that look at it still pick the right one.
fs::path temp_sibling(const fs::path& path);

// Renames `tmp` over `path` and fsyncs the folder; throws refocus::Error on failure.
void commit_temp(const fs::path& tmp, const fs::path& path);

// Test hook: makes the next atomic writes fail with ENOSPC after `bytes` bytes, as a full disk
// would (-1 disarms). Used by the tests to prove a failed save keeps the previous file.
void simulate_disk_full_after(long bytes);

std::string read_text_file(const fs::path& path);

// printf-style pattern ("frame_%04d.png") with one integer.
std::string format_pattern(const std::string& pattern, int index);

}  // namespace refocus
