#include "util/debug.h"

#include <map>

#include "util/error.h"

namespace refocus {

namespace {
std::map<std::string, std::string>& active() {
    static std::map<std::string, std::string> a;
    return a;
}
}  // namespace

const std::vector<std::pair<std::string, std::string>>& debug_names() {
    static const std::vector<std::pair<std::string, std::string>> names = {
        {"paper", "the paper preset's pre-training and loss terms, to stderr"},
        {"align", "the fast preset's ECC alignment of each frame at initialisation, to stderr"},
        {"masks", "which subject masks the track drops or fills, to stderr"},
        {"init-atlas=DIR", "start the fit from DIR/atlas_bg.exr (and atlas_fg.exr)"},
    };
    return names;
}

void set_debug(const std::string& spec) {
    size_t start = 0;
    while (start <= spec.size()) {
        const size_t comma = spec.find(',', start);
        const std::string item =
            spec.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
        start = comma == std::string::npos ? spec.size() + 1 : comma + 1;
        if (item.empty()) continue;
        const size_t eq = item.find('=');
        const std::string name = item.substr(0, eq);
        const std::string value = eq == std::string::npos ? "" : item.substr(eq + 1);
        bool known = false;
        std::string list;
        for (const auto& [n, help] : debug_names()) {
            const std::string base = n.substr(0, n.find('='));
            const bool wants_value = n.find('=') != std::string::npos;
            list += (list.empty() ? "" : ", ") + n;
            if (base == name && wants_value == !value.empty()) known = true;
        }
        if (!known) throw Error("--debug: unknown '" + item + "' (valid: " + list + ")");
        active()[name] = value;
    }
}

void clear_debug() {
    active().clear();
}

bool debug_enabled(const std::string& what) {
    return active().count(what) != 0;
}

std::string debug_value(const std::string& what) {
    auto it = active().find(what);
    return it == active().end() ? std::string() : it->second;
}

}  // namespace refocus
