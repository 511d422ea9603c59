#include "util/validate.h"

#include <cmath>
#include <cstdio>

#include "util/error.h"

namespace refocus {

namespace {
std::string num(double v) {
    if (std::isnan(v)) return "nan";
    if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
    char b[32];
    std::snprintf(b, sizeof b, "%.10g", v);
    return b;
}
}  // namespace

double checked_range(const std::string& what, double v, double lo, double hi, bool lo_open) {
    const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
    if (!ok)
        throw Error(what + " must be a number in " + (lo_open ? "(" : "[") + num(lo) + ", " +
                    num(hi) + "] (got " + num(v) + ")");
    return v;
}

long long checked_int(const std::string& what, double v, long long lo, long long hi) {
    const bool ok = std::isfinite(v) && v == std::floor(v) && v >= double(lo) && v <= double(hi);
    if (!ok)
        throw Error(what + " must be an integer in " + std::to_string(lo) + ".." +
                    std::to_string(hi) + " (got " + num(v) + ")");
    return static_cast<long long>(v);
}

}  // namespace refocus
