#include "util/timing.h"

#include <cstdio>
#include <mutex>
#include <vector>

#include "util/activity.h"
#include "util/debug.h"

namespace refocus {

namespace {

struct Row {
    std::string stage;
    double total = 0;
    long count = 0;
};
std::mutex g_mutex;
std::vector<Row> g_rows;

double since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

bool timing_enabled() {
    return debug_enabled("timing");
}

void add_timing(const std::string& stage, double seconds) {
    std::lock_guard<std::mutex> l(g_mutex);
    for (Row& r : g_rows)
        if (r.stage == stage) {
            r.total += seconds, ++r.count;
            return;
        }
    g_rows.push_back({stage, seconds, 1});
}

std::string timing_table() {
    std::lock_guard<std::mutex> l(g_mutex);
    if (g_rows.empty()) return "";
    std::string out = "timing (--debug timing): stage, total s, count, mean ms\n";
    char b[256];
    for (const Row& r : g_rows) {
        std::snprintf(b, sizeof b, "  %-40s %9.2f %7ld %10.1f\n", r.stage.c_str(), r.total, r.count,
                      1000.0 * r.total / double(r.count));
        out += b;
    }
    return out;
}

ScopedTiming::ScopedTiming(const char* stage) : m_stage(stage), m_on(timing_enabled()) {
    if (m_on) m_t0 = std::chrono::steady_clock::now();
}

ScopedTiming::~ScopedTiming() {
    if (m_on) add_timing(m_stage, since(m_t0));
}

StageClock::~StageClock() {
    end();
}

void StageClock::end() {
    if (!m_stage.empty() && timing_enabled()) add_timing(m_stage, since(m_t0));
    m_stage.clear();
}

void StageClock::next(const std::string& stage, const std::string& activity) {
    end();
    set_activity(activity);
    m_stage = stage;
    m_t0 = std::chrono::steady_clock::now();
}

}  // namespace refocus
