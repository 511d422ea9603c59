#include "progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

#include "util/activity.h"

namespace refocus {

std::string clock_text(double s) {
    if (s < 0) return "--:--";
    char b[32];
    std::snprintf(b, sizeof b, "%d:%02d", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
    return b;
}

StageProgress::StageProgress(std::string what, double line_every_s)
    : m_what(std::move(what)),
      m_every(line_every_s),
      m_tty(isatty(fileno(stderr))),
      m_start(std::chrono::steady_clock::now()) {}

StageProgress::~StageProgress() {
    stop_keeper();
}

void StageProgress::stop_keeper() {
    {
        std::lock_guard<std::mutex> l(m_mutex);
        m_stop = true;
    }
    m_wake.notify_all();
    if (m_keeper.joinable()) m_keeper.join();
}

void StageProgress::keep_alive(double every_s) {
    if (m_keeper.joinable()) return;
    {
        std::lock_guard<std::mutex> l(m_mutex);
        m_last_line = std::max(m_last_line, 0.0);  // the first line after every_s of silence
    }
    m_keeper = std::thread([this, every_s] {
        std::unique_lock<std::mutex> l(m_mutex);
        while (!m_wake.wait_for(l, std::chrono::seconds(1), [this] { return m_stop; })) {
            const double el =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - m_start).count();
            if (el - m_last_line < every_s) continue;
            const std::string now = current_activity();
            print_locked(m_fraction, now.empty() ? m_detail : now, true, false);
        }
    });
}

void StageProgress::update(double fraction, const std::string& detail, bool new_step) {
    print(std::clamp(fraction, 0.0, 1.0), detail, new_step, false);
}

void StageProgress::done(const std::string& detail) {
    stop_keeper();
    print(1.0, detail, true, true);
}

void StageProgress::print(double f, const std::string& detail, bool now, bool last) {
    std::lock_guard<std::mutex> l(m_mutex);
    m_fraction = f, m_detail = detail;
    print_locked(f, detail, now, last);
}

void StageProgress::print_locked(double f, const std::string& detail, bool now, bool last) {
    const double el =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - m_start).count();
    if (!m_tty && !now && el - m_last_line < m_every) return;
    m_last_line = el;
    const double eta = f > 0.02 && f < 1.0 ? el * (1.0 - f) / f : (f >= 1.0 ? 0.0 : -1.0);
    const std::string d = detail.empty() ? "" : ": " + detail;
    if (m_tty) {
        const int width = 24, fill = static_cast<int>(f * width);
        std::fprintf(stderr, "\r\033[K[%s%s] %3.0f%% %s%s  elapsed %s  ETA %s%s",
                     std::string(fill, '#').c_str(), std::string(width - fill, ' ').c_str(),
                     100 * f, m_what.c_str(), d.c_str(), clock_text(el).c_str(),
                     clock_text(eta).c_str(), last ? "\n" : "");
    } else {
        std::fprintf(stderr, "%s%s %.0f%% elapsed=%.1fs eta=%s\n", m_what.c_str(), d.c_str(),
                     100 * f, el, clock_text(eta).c_str());
    }
}

}  // namespace refocus
