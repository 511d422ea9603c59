#pragma once
// Wall time by stage for `--debug timing` (util/debug.h): the preparation's stages, the model's
// set-up, each part of a training step and of an export frame. Off (no clock read) unless the
// debug flag is set; the CLI prints timing_table() at the end of fit and export.
#include <chrono>
#include <string>

namespace refocus {

bool timing_enabled();
void add_timing(const std::string& stage, double seconds);
// The stages in the order first timed: total s, count, mean ms. "" when nothing was timed.
std::string timing_table();

// Times a scope as `stage`.
class ScopedTiming {
  public:
    explicit ScopedTiming(const char* stage);
    ~ScopedTiming();
    ScopedTiming(const ScopedTiming&) = delete;
    ScopedTiming& operator=(const ScopedTiming&) = delete;

  private:
    const char* m_stage;
    bool m_on;
    std::chrono::steady_clock::time_point m_t0;
};

// Consecutive stages of one piece of code: next() ends the stage before (and says what runs now
// in util/activity.h, for progress lines); the destructor ends the last.
class StageClock {
  public:
    StageClock() = default;
    ~StageClock();
    void next(const std::string& stage, const std::string& activity = "");
    void end();

  private:
    std::string m_stage;
    std::chrono::steady_clock::time_point m_t0;
};

}  // namespace refocus
