#pragma once
// Progress of a long CLI stage (ingest, preparation, export) on stderr: on a terminal, one line
// redrawn in place with a bar, the fraction done, elapsed time and ETA; otherwise (a log file, a
// pipe) a plain line every few seconds. stderr is unbuffered, so each line is in the file as it
// is written. The fit's own progress (cmd_fit.cpp) follows the same pattern with its figures.
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>

namespace refocus {

class StageProgress {
  public:
    explicit StageProgress(std::string what, double line_every_s = 5.0);
    ~StageProgress();
    // Repeats the line every `every_s` seconds that nothing else printed, with the engine's
    // current activity (util/activity.h) where it says one: no stage is silent for longer.
    void keep_alive(double every_s = 10.0);
    // `fraction` of the stage done (0..1); `detail` says what it is doing now. Off a terminal a
    // `new_step` is printed at once (a preparation step begins), the rest every few seconds.
    void update(double fraction, const std::string& detail = "", bool new_step = false);
    void done(const std::string& detail = "");  // ends the line

  private:
    void print(double fraction, const std::string& detail, bool now, bool last);
    void print_locked(double fraction, const std::string& detail, bool now, bool last);
    void stop_keeper();
    std::mutex m_mutex;
    std::condition_variable m_wake;
    std::thread m_keeper;
    bool m_stop = false;
    double m_fraction = 0;
    std::string m_detail;
    std::string m_what;
    double m_every;
    bool m_tty;
    std::chrono::steady_clock::time_point m_start;
    double m_last_line = -1e9;
};

// "m:ss", or "--:--" for a negative time.
std::string clock_text(double seconds);

}  // namespace refocus
