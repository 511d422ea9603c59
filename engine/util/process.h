#pragma once
// A child process started from an argument vector (posix_spawnp, no shell): its stdin is a pipe
// we write to, its stdout and stderr are captured (the last 64 KiB) for error messages.
#include <sys/types.h>

#include <memory>
#include <string>
#include <thread>
#include <vector>

namespace refocus {

class Subprocess {
  public:
    // Throws refocus::Error when the program cannot be started (e.g. not installed).
    explicit Subprocess(const std::vector<std::string>& argv);
    ~Subprocess();  // kills and reaps a child still running
    Subprocess(const Subprocess&) = delete;
    Subprocess& operator=(const Subprocess&) = delete;

    // Writes all of `n` bytes to the child's stdin; false (errno set) on failure, e.g. EPIPE
    // when the child has exited.
    bool write_stdin(const void* data, size_t n);
    // Closes stdin and waits: the exit code, or 128 + signal when it was killed.
    int wait();
    void kill();
    // What the child printed (after wait(): all of it, up to the last 64 KiB).
    std::string output() const { return m_output; }
    // The last non-empty line of output(), for one-line messages.
    std::string last_line() const;

  private:
    pid_t m_pid = -1;
    int m_stdin = -1;
    int m_out = -1;
    std::thread m_reader;
    std::string m_output;
    int m_status = -1;
};

}  // namespace refocus
