#pragma once
// What the preparation stage decided and why, as plain lines: kept for prepare.json and the
// fit's report, and forwarded to an optional sink (the CLI prints them, the GUI shows them).
// Progress goes to an optional stage sink: the name of each step as it begins and the share of
// the preparation done by then (the studio shows it with an ETA while the fit prepares).
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

    using StageSink = std::function<void(const std::string& name, double begin, double end)>;
    void set_stage_sink(StageSink sink) { m_stage_sink = std::move(sink); }
    // A step begins; it spans [begin, end] ⊂ [0, 1] of the work (rough shares of the time),
    // relative to the span set by set_span (a part of the preparation lays its own steps out).
    void stage(const std::string& name, double begin, double end) const {
        auto at = [&](double u) { return m_span_lo + u * (m_span_hi - m_span_lo); };
        if (m_stage_sink) m_stage_sink(name, at(begin), at(end));
    }
    void set_span(double lo, double hi) { m_span_lo = lo, m_span_hi = hi; }

  private:
    Sink m_sink;
    StageSink m_stage_sink;
    double m_span_lo = 0.0, m_span_hi = 1.0;
    std::vector<std::string> m_lines;
};

}  // namespace refocus
