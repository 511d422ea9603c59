#pragma once
// Diagnostics a developer switches on with `--debug <what>[,<what>...]` (CLI): dumps to stderr
// or a diagnostic start. Process-wide, set once at start-up before any fit runs.
#include <string>
#include <vector>

namespace refocus {

// "paper,align" or "init-atlas=DIR"; throws Error listing the valid names otherwise.
void set_debug(const std::string& spec);
void clear_debug();
bool debug_enabled(const std::string& what);
// The value given as what=value ("" when none).
std::string debug_value(const std::string& what);
// With `--debug memory`: one line on stderr with the process's resident memory at `stage`.
void debug_memory(const char* stage);
// The names set_debug accepts, with one line of help each.
const std::vector<std::pair<std::string, std::string>>& debug_names();

}  // namespace refocus
