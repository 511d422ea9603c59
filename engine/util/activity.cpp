#include "util/activity.h"

#include <mutex>

namespace refocus {

namespace {
std::mutex g_mutex;
std::string g_activity;
}  // namespace

void set_activity(const std::string& what) {
    std::lock_guard<std::mutex> l(g_mutex);
    g_activity = what;
}

std::string current_activity() {
    std::lock_guard<std::mutex> l(g_mutex);
    return g_activity;
}

}  // namespace refocus
