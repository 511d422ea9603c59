#pragma once
// JSON read from files the user can edit: nesting depth bounded before parsing (deep nesting
// would overflow the stack in the parser's users), every error names the file and the field.
#include <nlohmann/json.hpp>
#include <string>

#include "util/fs.h"

namespace refocus {

constexpr int kMaxJsonDepth = 64;

// Throws refocus::Error "<label>: JSON nested deeper than 64 levels (at byte N)".
void check_json_depth(const std::string& text, const std::string& label);
// Depth check, then parse; errors: "<label>: not valid JSON: <what, where>".
nlohmann::json parse_json_text(const std::string& text, const std::string& label);
nlohmann::json read_json_file(const fs::path& path);

// nlohmann's message without its "[json.exception.type_error.302] " prefix.
std::string json_error_text(const std::exception& e);
// "<label>: field '<field>' <problem>" as refocus::Error.
[[noreturn]] void json_field_error(const std::string& label, const std::string& field,
                                   const std::string& problem);
// A short rendering of a value for messages (type and at most ~60 characters, depth-safe).
std::string json_brief(const nlohmann::json& v);

}  // namespace refocus
