#pragma once
// Numbers checked where they enter (CLI flags, files): finite and in range, the valid range in
// the message.
#include <string>

namespace refocus {

// `v` in [lo, hi] ((lo, hi] when `lo_open`); else refocus::Error
// "<what> must be a number in (0, 10080] (got nan)".
double checked_range(const std::string& what, double v, double lo, double hi, bool lo_open = false);
// `v` a whole number in [lo, hi]; else refocus::Error "<what> must be an integer in 1..N (got x)".
long long checked_int(const std::string& what, double v, long long lo, long long hi);

}  // namespace refocus
