// The side of the focal plane of texels the radius leaves open, from a parallax field (depth.h,
// "Ambiguities"; depth_sides.h).
#include "edit/depth_sides.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <utility>

namespace refocus::depth_detail {

namespace {

// Where the focus barely moved, the ambiguous texels' distance from the focal plane,
// r = (hi − lo)/2, folds γ at the focal plane's γ0: r ≈ c·|γ − γ0|. γ0 is searched over γ's
// quantiles (its ends: no fold), c by least squares; the side is hi above γ0 and lo below (the
// global mirror is chosen afterwards). Returns the fit's explained share of r's variance.
double fold_sides(const LayerFit& L, const std::vector<Solution>& sols,
                  const std::vector<char>& ambiguous, std::vector<float>& v) {
    std::vector<std::pair<float, size_t>> g;
    for (size_t x = 0; x < ambiguous.size(); ++x)
        if (ambiguous[x]) g.push_back({L.gamma[x], x});
    if (g.size() < 16) return 0.0;
    std::sort(g.begin(), g.end());
    double W = 0, sr = 0, srr = 0;
    for (const auto& [gx, x] : g) {
        const double r = 0.5 * (sols[x].hi - sols[x].lo);
        W += L.seen[x], sr += L.seen[x] * r, srr += L.seen[x] * r * r;
    }
    const double var = srr - sr * sr / W;
    if (!(var > 0)) return 0.0;
    double best = std::numeric_limits<double>::infinity(), g0 = g.back().first;
    for (int q = 0; q <= 64; ++q) {
        const double c0 = g[std::min(g.size() - 1, size_t(q * (g.size() - 1) / 64))].first;
        double sab = 0, sbb = 0;
        for (const auto& [gx, x] : g) {
            const double r = 0.5 * (sols[x].hi - sols[x].lo), k = std::fabs(gx - c0);
            sab += L.seen[x] * r * k, sbb += L.seen[x] * k * k;
        }
        const double c = sbb > 0 ? sab / sbb : 0.0;
        const double res = srr - 2 * c * sab + c * c * sbb;  // Σ w (r − c·k)²
        if (res < best) best = res, g0 = c0;
    }
    for (const auto& [gx, x] : g) v[x] = float(gx > g0 ? sols[x].hi : sols[x].lo);
    return 1.0 - best / var;
}

// Where the side of the focal plane is ambiguous, a parallax field decides (depth.h): γ is
// affine in inverse depth with an unknown scale and sign. Where the texels the radius decided
// spread over 0.5 px and follow γ (|ρ| ≥ 0.3: a focus that moved), each ambiguous texel takes
// the side nearer a·γ + b, the line fitted to the decided texels, then refitted to every texel,
// decided and chosen, until no side changes; false (nothing written) where γ and the depths then
// do not correlate (|ρ| < 0.3). Otherwise fold_sides; false where its fold explains under 30 %
// of the texels' distances from the focal plane. False: the field says nothing here.
}  // namespace

bool parallax_sides(LayerFit& L, const std::vector<Solution>& sols,
                    const std::vector<float>& confident) {
    const size_t n = L.d.size();
    std::vector<float> v(n, 0.0f);
    std::vector<char> use(n, 0), ambiguous(n, 0);
    for (size_t x = 0; x < n; ++x) {
        if (!(L.seen[x] > 0) || !std::isfinite(L.gamma[x])) continue;
        use[x] = 1;
        ambiguous[x] = !(confident[x] > 0);
        v[x] = ambiguous[x] ? float(sols[x].lo) : L.d[x];
    }
    struct Line {
        double a = 0, b = 0, rho = 0, sd = 0;
    };
    auto fit = [&](bool sure_only) {  // weighted least squares of v on γ
        double W = 0, sg = 0, sv = 0;
        for (size_t x = 0; x < n; ++x)
            if (use[x] && !(sure_only && ambiguous[x]))
                W += L.seen[x], sg += L.seen[x] * L.gamma[x], sv += L.seen[x] * v[x];
        Line line;
        if (!(W > 0)) return line;
        const double mg = sg / W, mv = sv / W;
        double sgg = 0, svv = 0, sgv = 0;
        for (size_t x = 0; x < n; ++x)
            if (use[x] && !(sure_only && ambiguous[x])) {
                const double g = L.gamma[x] - mg, d = v[x] - mv;
                sgg += L.seen[x] * g * g, svv += L.seen[x] * d * d, sgv += L.seen[x] * g * d;
            }
        line.a = sgg > 0 ? sgv / sgg : 0.0;
        line.b = mv - line.a * mg;
        line.rho = sgg > 0 && svv > 0 ? sgv / std::sqrt(sgg * svv) : 0.0;
        line.sd = std::sqrt(svv / W);
        return line;
    };
    Line line = fit(true);
    if (line.sd < 0.5 || !(std::fabs(line.rho) >= 0.3)) {
        if (!(fold_sides(L, sols, ambiguous, v) >= 0.3)) return false;
    } else {
        for (int round = 0; round < 20; ++round) {
            if (round > 0) line = fit(false);
            int changed = 0;
            for (size_t x = 0; x < n; ++x) {
                if (!ambiguous[x]) continue;
                const double want = line.a * L.gamma[x] + line.b;
                const float side =
                    float(std::fabs(sols[x].hi - want) < std::fabs(sols[x].lo - want) ? sols[x].hi
                                                                                      : sols[x].lo);
                changed += side != v[x];
                v[x] = side;
            }
            if (!changed && round > 0) break;
        }
        if (!(std::fabs(line.rho) >= 0.3)) return false;
    }
    for (size_t x = 0; x < n; ++x)
        if (ambiguous[x]) L.d[x] = v[x];
    return true;
}

}  // namespace refocus::depth_detail
