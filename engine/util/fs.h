#pragma once
#include <filesystem>
#include <string>
#include <vector>

namespace refocus {

namespace fs = std::filesystem;

// Writes `bytes` to `path` atomically: a temporary file in the same folder, fsync, rename,
// fsync of the folder. On any failure (full disk, no permission) the temporary is removed, the
// previous file at `path` is left untouched and refocus::Error names the file and the cause.
void write_file_atomic(const fs::path& path, const std::string& bytes);

// A temporary sibling name for `path` ("<dir>/.<name>.tmp-<pid>-<n><ext>"), keeping the
// extension so that format writers that look at it still pick the right one.
fs::path temp_sibling(const fs::path& path);
// Removes the temporaries (temp_sibling's names, files or folders) in `dir` whose process no
// longer runs on this machine: what a killed command left. Errors are ignored.
void remove_stale_temporaries(const fs::path& dir);

// Renames `tmp` over `path` and fsyncs the folder; throws refocus::Error on failure.
void commit_temp(const fs::path& tmp, const fs::path& path);

// A fresh hidden temporary folder beside `dir` (same file system, so it can be renamed there).
fs::path make_temp_dir_beside(const fs::path& dir);

// Publishes the folder `tmp` (built completely) as `dest`: one rename when `dest` is absent or
// empty, else entry by entry (sub-folders merged, files replaced), with the entries named in
// `last` moved last (the file that marks the folder complete). `tmp` is gone afterwards.
void publish_dir(const fs::path& tmp, const fs::path& dest,
                 const std::vector<std::string>& last = {});

// Test hook: makes the next atomic writes fail with ENOSPC after `bytes` bytes, as a full disk
// would (-1 disarms). Used by the tests to prove a failed save keeps the previous file.
void simulate_disk_full_after(long bytes);

std::string read_text_file(const fs::path& path);

// A frame pattern ("frame_%04d.png"): exactly one %d or %0Nd (N <= 10), "%%" is a literal
// percent, everything else literal. Parsed, never handed to printf.
struct FramePattern {
    std::string prefix, suffix;
    int width = 0;  // %0Nd: N digits, zero-padded; %d: 0
    std::string format(long index) const;
};
// Throws refocus::Error "<label>: bad frame pattern '...': <why>" (label: the file/field that
// holds it; empty: the pattern alone).
FramePattern parse_frame_pattern(const std::string& pattern, const std::string& label = "");
// Why `pattern` is not a valid frame pattern, or "" when it is.
std::string frame_pattern_problem(const std::string& pattern);

// parse_frame_pattern(pattern).format(index).
std::string format_pattern(const std::string& pattern, int index);

}  // namespace refocus
