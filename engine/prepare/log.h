#pragma once
// What the preparation stage decided and why, as plain lines: kept for prepare.json and the
// fit's report, and forwarded to an optional sink (the CLI prints them, the GUI shows them).
#include <functional>
#include <string>
#include <vector>

namespace refocus {

class PrepareLog {
  public:
    using Sink = std::function<void(const std::string&)>;
    PrepareLog() = default;
    explicit PrepareLog(Sink sink) : m_sink(std::move(sink)) {}
    void info(const std::string& line) {
        m_lines.push_back(line);
        if (m_sink) m_sink(line);
    }
    const std::vector<std::string>& lines() const { return m_lines; }

  private:
    Sink m_sink;
    std::vector<std::string> m_lines;
};

}  // namespace refocus
