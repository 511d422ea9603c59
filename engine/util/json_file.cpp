#include "util/json_file.h"

#include "util/error.h"

namespace refocus {

void check_json_depth(const std::string& text, const std::string& label) {
    int depth = 0;
    bool in_string = false, escape = false;
    for (size_t i = 0; i < text.size(); ++i) {
        const char c = text[i];
        if (in_string) {
            if (escape)
                escape = false;
            else if (c == '\\')
                escape = true;
            else if (c == '"')
                in_string = false;
            continue;
        }
        if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            if (++depth > kMaxJsonDepth)
                throw Error(file_error(label, "JSON nested deeper than " +
                                                  std::to_string(kMaxJsonDepth) +
                                                  " levels (at byte " + std::to_string(i) + ")"));
        } else if (c == ']' || c == '}') {
            --depth;
        }
    }
}

std::string json_error_text(const std::exception& e) {
    std::string s = e.what();
    if (s.rfind("[json.exception.", 0) == 0) {
        const size_t end = s.find("] ");
        if (end != std::string::npos) s = s.substr(end + 2);
    }
    for (char& c : s)
        if (c == '\n') c = ' ';
    return s;
}

nlohmann::json parse_json_text(const std::string& text, const std::string& label) {
    check_json_depth(text, label);
    try {
        return nlohmann::json::parse(text);
    } catch (const nlohmann::json::exception& e) {
        throw Error(file_error(label, "not valid JSON: " + json_error_text(e)));
    }
}

nlohmann::json read_json_file(const fs::path& path) {
    return parse_json_text(read_text_file(path), path.string());
}

void json_field_error(const std::string& label, const std::string& field,
                      const std::string& problem) {
    throw Error(file_error(label, "field '" + field + "' " + problem));
}

std::string json_brief(const nlohmann::json& v) {
    if (v.is_object()) return "an object";
    if (v.is_array()) return "an array";
    std::string s = v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    if (s.size() > 60) s = s.substr(0, 57) + "...";
    return s;
}

}  // namespace refocus
