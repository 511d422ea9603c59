#include "util/debug.h"

#include <chrono>
#include <cstdio>
#include <fstream>
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
        {"memory", "resident memory (anonymous, and mapped clip arrays) at each stage, to stderr"},
        {"timing",
         "wall time by stage (preparation, set-up, each part of a step, export), to "
         "stderr at the end"},
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

void debug_memory(const char* stage) {
    if (!debug_enabled("memory")) return;
    std::ifstream f("/proc/self/status");
    std::string line, anon = "?", file = "?", peak = "?";
    auto value = [](const std::string& l) {  // "RssAnon:\t  123456 kB" -> "123456"
        const size_t a = l.find_first_of("0123456789");
        return a == std::string::npos ? std::string("?") : l.substr(a, l.find(' ', a) - a);
    };
    while (std::getline(f, line)) {
        if (line.rfind("RssAnon:", 0) == 0) anon = value(line);
        if (line.rfind("RssFile:", 0) == 0) file = value(line);
        if (line.rfind("VmHWM:", 0) == 0) peak = value(line);
    }
    auto mb = [](const std::string& kb) {
        return kb == "?" ? kb : std::to_string(std::stoll(kb) / 1024);
    };
    static const auto start = std::chrono::steady_clock::now();  // the first stage's time
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr,
                 "memory: %-36s %7.1f s: anonymous %6s MB, file-backed %6s MB, peak %6s MB\n",
                 stage, s, mb(anon).c_str(), mb(file).c_str(), mb(peak).c_str());
}

}  // namespace refocus
