// Inverse depth from the fit's radius maps (seed 001 eq. 1.12 with A = 1): the alternating
// exact 1-D solves of fit_depth, and build_depth and project_depth, which feed it a fitted
// model; see depth.h.
#include "edit/depth.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <mutex>

#include "edit/depth_sides.h"
#include "fit/fit_engine.h"
#include "util/error.h"

namespace refocus {

namespace {

using depth_detail::LayerFit;
using depth_detail::parallax_sides;
using depth_detail::Solution;

// One term w·(r − |z − a|)² of a 1-D problem.
struct Obs {
    double a, r, w;
};

// Exact  argmin_z Σ w_i (r_i − |z − a_i|)²  (see depth.h). Between sorted breakpoints the signs
// s_i = sign(z − a_i) are fixed and the cost is Σ w_i (z − (a_i + s_i·r_i))², minimised by a
// clamped weighted mean. `best` is the global minimum; lo/hi the smallest and largest minimiser
// whose cost is within tie·Σw of it (hi − lo large: the side of the focal plane is ambiguous).
// `obs` is reordered. All NaN when there is no weight.
Solution solve_abs(std::vector<Obs>& obs, double tie) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    double W = 0, S = 0, S2 = 0;  // Σw, Σw·c, Σw·c² with c_i = a_i + s_i·r_i, all s_i = −1 first
    for (const Obs& o : obs) {
        const double c = o.a - o.r;
        W += o.w;
        S += o.w * c;
        S2 += o.w * c * c;
    }
    if (!(W > 0)) return {nan, nan, nan};
    std::sort(obs.begin(), obs.end(), [](const Obs& x, const Obs& y) { return x.a < y.a; });
    const double inf = std::numeric_limits<double>::infinity();
    struct Cand {
        double z, cost;
    };
    std::vector<Cand> cands;
    cands.reserve(obs.size() + 1);
    auto consider = [&](double lo, double hi) {
        const double z = std::min(std::max(S / W, lo), hi);
        cands.push_back({z, W * z * z - 2 * z * S + S2});
    };
    consider(-inf, obs.front().a);
    for (size_t i = 0; i < obs.size(); ++i) {
        const Obs& o = obs[i];  // z passes a_i: s_i −1 → +1
        S += 2 * o.w * o.r;
        S2 += 4 * o.w * o.a * o.r;
        consider(o.a, i + 1 < obs.size() ? obs[i + 1].a : inf);
    }
    Solution sol{0, inf, -inf};
    double best = inf;
    for (const Cand& c : cands)
        if (c.cost < best) best = c.cost, sol.best = c.z;
    for (const Cand& c : cands)
        if (c.cost <= best + tie * W)
            sol.lo = std::min(sol.lo, c.z), sol.hi = std::max(sol.hi, c.z);
    return sol;
}

// Push-pull fill of the texels with weight 0 from their neighbours (weighted pyramid).
void fill_unseen(std::vector<float>& v, const std::vector<float>& w, int W, int H) {
    bool any_missing = false;
    for (float x : w) any_missing |= !(x > 0);
    if (!any_missing) return;
    if (W == 1 && H == 1) {
        v[0] = 0.0f;
        return;
    }
    const int cw = (W + 1) / 2, ch = (H + 1) / 2;
    std::vector<float> cv(size_t(cw) * ch, 0.0f), cwt(size_t(cw) * ch, 0.0f);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const size_t i = size_t(y) * W + x, c = size_t(y / 2) * cw + x / 2;
            if (w[i] > 0) {
                cv[c] += w[i] * v[i];
                cwt[c] += w[i];
            }
        }
    for (size_t c = 0; c < cv.size(); ++c)
        if (cwt[c] > 0) cv[c] /= cwt[c];
    fill_unseen(cv, cwt, cw, ch);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const size_t i = size_t(y) * W + x;
            if (w[i] > 0) continue;
            const float cx = std::clamp((x + 0.5f) / 2 - 0.5f, 0.0f, float(cw - 1));
            const float cy = std::clamp((y + 0.5f) / 2 - 0.5f, 0.0f, float(ch - 1));
            const int x0 = int(cx), y0 = int(cy), x1 = std::min(x0 + 1, cw - 1),
                      y1 = std::min(y0 + 1, ch - 1);
            const float fx = cx - x0, fy = cy - y0;
            auto at = [&](int xx, int yy) { return cv[size_t(yy) * cw + xx]; };
            v[i] = (at(x0, y0) * (1 - fx) + at(x1, y0) * fx) * (1 - fy) +
                   (at(x0, y1) * (1 - fx) + at(x1, y1) * fx) * fy;
        }
}

// A frame pixel used by the focus/offset updates.
struct Px {
    int x0, x1, y0, y1;
    float fx, fy, r;
    bool fg;
};

inline float sample_px(const LayerFit& L, const Px& p) {
    auto at = [&](int x, int y) { return L.d[size_t(y) * L.W + x]; };
    return (at(p.x0, p.y0) * (1 - p.fx) + at(p.x1, p.y0) * p.fx) * (1 - p.fy) +
           (at(p.x0, p.y1) * (1 - p.fx) + at(p.x1, p.y1) * p.fx) * p.fy;
}

float median_of(std::vector<float>& v) {
    if (v.empty()) return std::numeric_limits<float>::quiet_NaN();
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
}

// Initial focus: |f_t − f_t'| ≈ median radius at t' of the background texels sharpest at t, then
// classical MDS on a line (top eigenvector of −½·J·D²·J by power iteration).
std::vector<double> initial_focus(const LayerFit& L, int T) {
    std::vector<std::vector<int>> sharp(T);  // per frame: texels in its sharpest 10 %
    {
        std::vector<std::vector<std::pair<float, int>>> per(T);
        for (int x = 0; x < L.W * L.H; ++x)
            for (int k = L.start[x]; k < L.start[x + 1]; ++k)
                per[L.obs[k].t].push_back({L.obs[k].r, x});
        for (int t = 0; t < T; ++t) {
            auto& v = per[t];
            const size_t n = std::max<size_t>(1, v.size() / 10);
            if (v.empty()) continue;
            std::nth_element(v.begin(), v.begin() + (n - 1), v.end());
            const size_t stride = std::max<size_t>(1, n / 400);
            for (size_t i = 0; i < n; i += stride) sharp[t].push_back(v[i].second);
        }
    }
    auto radius_at = [&](int x, int t) -> float {  // obs of texel x are sorted by frame
        auto b = L.obs.begin() + L.start[x], e = L.obs.begin() + L.start[x + 1];
        auto it =
            std::lower_bound(b, e, t, [](const LayerFit::TexObs& o, int tt) { return o.t < tt; });
        return (it != e && it->t == t) ? it->r : std::numeric_limits<float>::quiet_NaN();
    };
    std::vector<double> D(size_t(T) * T, std::numeric_limits<double>::quiet_NaN());
    std::vector<float> vals;
    for (int t = 0; t < T; ++t)
        for (int u = 0; u < T; ++u) {
            vals.clear();
            for (int x : sharp[t]) {
                const float r = radius_at(x, u);
                if (std::isfinite(r)) vals.push_back(r);
            }
            if (!vals.empty()) D[size_t(t) * T + u] = median_of(vals);
        }
    double sum = 0;
    int n = 0;
    for (int t = 0; t < T; ++t)
        for (int u = 0; u < T; ++u) {
            const double a = D[size_t(t) * T + u], b = D[size_t(u) * T + t];
            double s = std::isfinite(a) && std::isfinite(b) ? 0.5 * (a + b)
                       : std::isfinite(a)                   ? a
                                                            : b;
            if (t == u) s = 0;
            D[size_t(t) * T + u] = s;
            if (std::isfinite(s)) sum += s, ++n;
        }
    for (double& v : D)
        if (!std::isfinite(v)) v = n ? sum / n : 0.0;
    // B = −½ J D² J
    std::vector<double> B(size_t(T) * T), row(T, 0), col(T, 0);
    double all = 0;
    for (int t = 0; t < T; ++t)
        for (int u = 0; u < T; ++u) {
            const double q = D[size_t(t) * T + u] * D[size_t(t) * T + u];
            row[t] += q / T;
            col[u] += q / T;
            all += q / (double(T) * T);
        }
    for (int t = 0; t < T; ++t)
        for (int u = 0; u < T; ++u)
            B[size_t(t) * T + u] =
                -0.5 * (D[size_t(t) * T + u] * D[size_t(t) * T + u] - row[t] - col[u] + all);
    std::vector<double> v(T), nv(T);
    for (int t = 0; t < T; ++t) v[t] = 1.0 + 0.01 * t;  // not orthogonal to a ramp
    double lambda = 0;
    for (int it = 0; it < 200; ++it) {
        double norm = 0;
        for (int t = 0; t < T; ++t) {
            nv[t] = 0;
            for (int u = 0; u < T; ++u) nv[t] += B[size_t(t) * T + u] * v[u];
            norm += nv[t] * nv[t];
        }
        norm = std::sqrt(norm);
        if (!(norm > 1e-12)) return std::vector<double>(T, 0.0);
        lambda = norm;
        for (int t = 0; t < T; ++t) v[t] = nv[t] / norm;
    }
    for (double& x : v) x *= std::sqrt(lambda);
    return v;
}

torch::Tensor cpu_float(const torch::Tensor& t) {
    return t.defined() ? t.detach().to(torch::kCPU, torch::kFloat).contiguous() : t;
}

void check_shape(const torch::Tensor& t, std::vector<int64_t> want, const char* what) {
    if (!t.defined() || t.sizes().vec() != want)
        throw Error(std::string("fit_depth: ") + what + " has the wrong shape");
}

// The fit's inputs as flat CPU float arrays: radius [T,H,W], UV per layer [T,H,W,2], alpha
// [T,1,H,W] (with two layers; a pixel belongs to the foreground where alpha > 0.5).
struct DepthInput {
    int T = 0, H = 0, W = 0;
    bool two = false;
    const float* R = nullptr;
    const float* UB = nullptr;
    const float* UF = nullptr;
    const float* AL = nullptr;
    size_t HW = 0;
};

// Splats every valid pixel bilinearly onto its layer's texels, aggregated per (texel, frame),
// and returns a strided subset of pixels per frame for the focus/offset updates.
std::vector<std::vector<Px>> splat_pixels(const DepthInput& in, LayerFit* layers, int nl,
                                          int focus_samples) {
    const int T = in.T, H = in.H, Wd = in.W;
    const bool two = in.two;
    const float* R = in.R;
    const float* UB = in.UB;
    const float* UF = in.UF;
    const float* AL = in.AL;
    const size_t HW = in.HW;
    const int step =
        std::max(1, int(std::ceil(std::sqrt(double(HW) / std::max(1, focus_samples)))));
    std::vector<std::vector<Px>> px(T);
    std::vector<std::vector<float>> sw(nl), swr(nl);
    std::vector<std::vector<std::pair<int, LayerFit::TexObs>>> raw(nl);
    for (int l = 0; l < nl; ++l) {
        sw[l].assign(size_t(layers[l].W) * layers[l].H, 0.0f);
        swr[l].assign(sw[l].size(), 0.0f);
    }
    for (int t = 0; t < T; ++t) {
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < Wd; ++x) {
                const size_t i = size_t(t) * HW + size_t(y) * Wd + x;
                const float r = R[i];
                const bool fg = two && AL[i] > 0.5f;
                const float* uv = (fg ? UF : UB) + 2 * i;
                if (!std::isfinite(r) || !std::isfinite(uv[0]) || !std::isfinite(uv[1])) continue;
                LayerFit& L = layers[fg];
                Px p;
                preview_atlas_coord(uv[0], L.W, p.x0, p.x1, p.fx);
                preview_atlas_coord(uv[1], L.H, p.y0, p.y1, p.fy);
                p.r = std::max(r, 0.0f);
                p.fg = fg;
                const float wts[4] = {(1 - p.fx) * (1 - p.fy), p.fx * (1 - p.fy), (1 - p.fx) * p.fy,
                                      p.fx * p.fy};
                const size_t tex[4] = {size_t(p.y0) * L.W + p.x0, size_t(p.y0) * L.W + p.x1,
                                       size_t(p.y1) * L.W + p.x0, size_t(p.y1) * L.W + p.x1};
                for (int k = 0; k < 4; ++k) {
                    sw[fg][tex[k]] += wts[k];
                    swr[fg][tex[k]] += wts[k] * p.r;
                }
                if (y % step == 0 && x % step == 0) px[t].push_back(p);
            }
        for (int l = 0; l < nl; ++l)
            for (size_t k = 0; k < sw[l].size(); ++k)
                if (sw[l][k] > 1e-6f) {
                    raw[l].push_back({int(k), {t, sw[l][k], swr[l][k] / sw[l][k]}});
                    sw[l][k] = swr[l][k] = 0.0f;
                }
    }
    for (int l = 0; l < nl; ++l) {  // counting sort by texel (stable: frames stay sorted)
        LayerFit& L = layers[l];
        const size_t n = size_t(L.W) * L.H;
        L.start.assign(n + 1, 0);
        L.seen.assign(n, 0.0f);
        L.d.assign(n, 0.0f);
        for (auto& e : raw[l]) ++L.start[e.first + 1], L.seen[e.first] += e.second.w;
        for (size_t k = 0; k < n; ++k) L.start[k + 1] += L.start[k];
        L.obs.resize(raw[l].size());
        std::vector<int> fillp(L.start.begin(), L.start.end() - 1);
        for (auto& e : raw[l]) L.obs[fillp[e.first]++] = e.second;
    }
    return px;
}

// The alternating minimisation over the texels' depths d, the frames' focus f and the
// foreground's offsets o (depth.h, "Method").
struct AlternatingFit {
    LayerFit* layers;
    int nl, T;
    bool two;
    const std::vector<std::vector<Px>>& px;
    const DepthFitOptions& opts;
    std::vector<double> f, o;
    std::vector<Obs> buf;
    std::vector<Solution> sols;
    std::vector<float> confident, ref;

    AlternatingFit(LayerFit* layers_, int nl_, int T_, bool two_,
                   const std::vector<std::vector<Px>>& px_, const DepthFitOptions& opts_)
        : layers(layers_),
          nl(nl_),
          T(T_),
          two(two_),
          px(px_),
          opts(opts_),
          f(T_, 0.0),
          o(T_, 0.0) {}

    // Texels: exact per-texel solve. Where the side of the focal plane is ambiguous (seen at one
    // focus only), the side of the confident neighbours (push-pull of the texels the data
    // decided) when they clearly lie on one side, else the rule: background behind, foreground
    // in front.
    void update_texels() {
        for (int l = 0; l < nl; ++l) {
            LayerFit& L = layers[l];
            const size_t n = L.d.size();
            sols.assign(n, Solution{0, 0, 0});
            confident.assign(n, 0.0f);
            bool any_confident = false;
            for (size_t x = 0; x < n; ++x) {
                if (L.start[x] == L.start[x + 1]) continue;
                buf.clear();
                for (int k = L.start[x]; k < L.start[x + 1]; ++k) {
                    const auto& ob = L.obs[k];
                    buf.push_back({f[ob.t] - (l ? o[ob.t] : 0.0), ob.r, ob.w});
                }
                sols[x] = solve_abs(buf, opts.tie_px2);
                L.d[x] = float(sols[x].best);
                if (!sols[x].ambiguous()) confident[x] = L.seen[x], any_confident = true;
            }
            if (!L.gamma.empty() && parallax_sides(L, sols, confident)) {
                fill_unseen(L.d, L.seen, L.W, L.H);
                continue;
            }
            ref = L.d;
            if (any_confident) fill_unseen(ref, confident, L.W, L.H);
            for (size_t x = 0; x < n; ++x)
                if (L.seen[x] > 0 && !(confident[x] > 0)) {
                    const Solution& s = sols[x];
                    const double mid = 0.5 * (s.lo + s.hi),
                                 off = any_confident ? ref[x] - mid : 0.0;
                    const bool hi = std::fabs(off) > 0.25 * (s.hi - s.lo) ? off > 0 : l == 1;
                    L.d[x] = float(hi ? s.hi : s.lo);
                }
            fill_unseen(L.d, L.seen, L.W, L.H);
        }
    }
    float depth_px(const Px& p, int t) const {
        return sample_px(layers[p.fg], p) + (p.fg ? float(o[t]) : 0.0f);
    }
    double cost() const {
        double c = 0;
        size_t n = 0;
        for (int t = 0; t < T; ++t)
            for (const Px& p : px[t]) {
                const double e = p.r - std::fabs(depth_px(p, t) - f[t]);
                c += e * e;
                ++n;
            }
        return n ? c / n : 0.0;
    }
    void update_frames() {
        for (int t = 0; t < T; ++t) {  // focus: a = d_t(p)
            buf.clear();
            for (const Px& p : px[t]) buf.push_back({depth_px(p, t), p.r, 1.0});
            if (!buf.empty()) f[t] = solve_abs(buf, 0.0).best;
        }
        if (!two) return;
        double sum = 0;
        int n = 0;
        for (int t = 0; t < T; ++t) {  // foreground offset: a = f_t − D_f(p)
            buf.clear();
            for (const Px& p : px[t])
                if (p.fg) buf.push_back({f[t] - sample_px(layers[1], p), p.r, 1.0});
            if (buf.empty()) continue;
            o[t] = solve_abs(buf, 0.0).best;
            sum += o[t], ++n;
        }
        if (!n) return;
        const double m = sum / n;  // gauge: mean offset 0, moved into D_f
        for (double& x : o) x -= m;
        for (float& x : layers[1].d) x += float(m);
    }
    // Rounds from the focus f0 until the cost stops falling; returns the lowest cost.
    double run(const std::vector<double>& f0, int& rounds) {
        f = f0;
        std::fill(o.begin(), o.end(), 0.0);
        update_texels();
        double prev = cost();
        for (rounds = 1; rounds <= opts.max_rounds; ++rounds) {
            update_frames();
            update_texels();
            const double c = cost();
            const bool stop = prev - c < opts.stop_rel * prev;
            prev = std::min(prev, c);
            if (stop) break;
        }
        return prev;
    }
};

// Whether to mirror the depths globally: the foreground is nearer; with one layer, most pixels
// lie behind the focal plane.
bool choose_mirror(const AlternatingFit& fit) {
    const LayerFit* layers = fit.layers;
    const int T = fit.T;
    if (fit.two) {
        std::vector<float> vb, vf;
        for (size_t x = 0; x < layers[0].d.size(); ++x)
            if (layers[0].seen[x] > 0) vb.push_back(layers[0].d[x]);
        double mo = 0;
        for (double x : fit.o) mo += x / T;
        for (size_t x = 0; x < layers[1].d.size(); ++x)
            if (layers[1].seen[x] > 0) vf.push_back(layers[1].d[x] + float(mo));
        if (!vb.empty() && !vf.empty()) return median_of(vf) < median_of(vb);
        return false;
    }
    long behind = 0;
    for (int t = 0; t < T; ++t)
        for (const Px& p : fit.px[t]) behind += fit.depth_px(p, t) < fit.f[t] ? 1 : -1;
    return behind < 0;
}

// The fitted depths, mirrored if `mirror`, shifted so that the farthest point is at 0.
DepthModel to_depth_model(const AlternatingFit& fit, bool mirror) {
    const LayerFit* layers = fit.layers;
    const int T = fit.T, nl = fit.nl;
    const bool two = fit.two;
    const std::vector<double>& f = fit.f;
    const std::vector<double>& o = fit.o;
    const double sgn = mirror ? -1.0 : 1.0;
    double lo = std::numeric_limits<double>::infinity(), omin = 0;
    for (int t = 0; t < T; ++t) omin = std::min(omin, sgn * o[t]);
    for (int l = 0; l < nl; ++l)
        for (float x : layers[l].d) lo = std::min(lo, sgn * x + (l ? omin : 0.0));
    if (!std::isfinite(lo)) lo = 0;

    DepthModel m;
    auto to_image = [&](const LayerFit& L) {
        Image img(L.W, L.H, 1);
        for (size_t x = 0; x < L.d.size(); ++x) {
            const double v = sgn * L.d[x] - lo;
            img.pixels[x] = std::isfinite(v) ? float(v) : 0.0f;
        }
        return img;
    };
    m.bg_atlas = to_image(layers[0]);
    if (two) m.fg_atlas = to_image(layers[1]);
    m.focus.resize(T);
    m.fg_offset.assign(T, 0.0f);
    for (int t = 0; t < T; ++t) {
        const double v = sgn * f[t] - lo;
        m.focus[t] = std::isfinite(v) ? float(v) : 0.0f;
        if (two) m.fg_offset[t] = std::isfinite(o[t]) ? float(sgn * o[t]) : 0.0f;
    }
    return m;
}

// rms of r − |d − f| over every valid pixel, through the same sampling as frame_depth.
double rms_over_pixels(const DepthInput& in, const DepthModel& m) {
    const bool two = in.two;
    const float* R = in.R;
    const float* UB = in.UB;
    const float* UF = in.UF;
    const float* AL = in.AL;
    const size_t HW = in.HW;
    double se = 0;
    size_t n = 0;
    for (int t = 0; t < in.T; ++t)
        for (size_t i = 0; i < HW; ++i) {
            const size_t k = size_t(t) * HW + i;
            const bool fg = two && AL[k] > 0.5f;
            const float* uv = (fg ? UF : UB) + 2 * k;
            if (!std::isfinite(R[k]) || !std::isfinite(uv[0]) || !std::isfinite(uv[1])) continue;
            const float d = m.depth_at_atlas(fg ? DepthModel::Foreground : DepthModel::Background,
                                             uv[0], uv[1], t);
            const double e = std::max(R[k], 0.0f) - std::fabs(d - m.focus[t]);
            se += e * e;
            ++n;
        }
    return n ? std::sqrt(se / n) : 0.0;
}

}  // namespace

DepthModel fit_depth(const torch::Tensor& radius_in, const torch::Tensor& uv_bg_in,
                     const torch::Tensor& uv_fg_in, const torch::Tensor& alpha_in, int bg_h,
                     int bg_w, int fg_h, int fg_w, const DepthFitOptions& opts,
                     const torch::Tensor& bg_parallax) {
    if (!radius_in.defined() || radius_in.dim() != 3)
        throw Error("fit_depth: radius must be [T,H,W]");
    const int T = int(radius_in.size(0)), H = int(radius_in.size(1)), Wd = int(radius_in.size(2));
    if (T < 1 || H < 1 || Wd < 1 || bg_h < 1 || bg_w < 1) throw Error("fit_depth: empty input");
    const bool two = uv_fg_in.defined() && alpha_in.defined() && fg_h > 0 && fg_w > 0;
    check_shape(uv_bg_in, {T, H, Wd, 2}, "uv_bg");
    if (two) {
        check_shape(uv_fg_in, {T, H, Wd, 2}, "uv_fg");
        check_shape(alpha_in, {T, 1, H, Wd}, "alpha");
    }
    const torch::Tensor radius = cpu_float(radius_in), uvb = cpu_float(uv_bg_in),
                        uvf = two ? cpu_float(uv_fg_in) : torch::Tensor(),
                        alpha = two ? cpu_float(alpha_in) : torch::Tensor();
    DepthInput in;
    in.T = T, in.H = H, in.W = Wd;
    in.two = two;
    in.R = radius.data_ptr<float>();
    in.UB = uvb.data_ptr<float>();
    in.UF = two ? uvf.data_ptr<float>() : nullptr;
    in.AL = two ? alpha.data_ptr<float>() : nullptr;
    in.HW = size_t(H) * Wd;

    LayerFit layers[2];
    layers[0].W = bg_w, layers[0].H = bg_h;
    if (two) layers[1].W = fg_w, layers[1].H = fg_h;
    const int nl = two ? 2 : 1;
    const std::vector<std::vector<Px>> px = splat_pixels(in, layers, nl, opts.focus_samples);
    if (bg_parallax.defined() && bg_parallax.numel() == int64_t(bg_h) * bg_w) {
        const torch::Tensor g = cpu_float(bg_parallax.reshape({bg_h, bg_w}));
        layers[0].gamma.assign(g.data_ptr<float>(), g.data_ptr<float>() + g.numel());
    }

    // Two starts: the MDS focus, and a constant focus (which wins where the focus never moves).
    AlternatingFit fit(layers, nl, T, two, px, opts);
    int rounds_a = 0, rounds_b = 0;
    const std::vector<double> f_mds = initial_focus(layers[0], T);
    const double cost_a = fit.run(f_mds, rounds_a);
    std::vector<double> fa = fit.f, oa = fit.o;
    std::vector<float> da[2] = {layers[0].d, layers[1].d};
    const double cost_b = fit.run(std::vector<double>(T, 0.0), rounds_b);
    if (cost_a <= cost_b) {
        fit.f = fa, fit.o = oa;
        layers[0].d = da[0], layers[1].d = da[1];
    }

    // Global mirror, then the shift.
    DepthModel m = to_depth_model(fit, choose_mirror(fit));
    m.rounds = cost_a <= cost_b ? rounds_a : rounds_b;
    m.rms_px = rms_over_pixels(in, m);
    return m;
}

// ---------------------------------------------------------------- from a fit

DepthModel build_depth(FitEngine& engine, const DepthFitOptions& opts) {
    if (!engine.has_atlas())
        throw Error("depth: the perframe preset has no atlas to hold depth (use fast or paper)");
    torch::NoGradGuard no_grad;
    const FitData& data = engine.data();
    std::vector<torch::Tensor> ub, uf, al;
    for (int t = 0; t < data.frames; ++t) {  // render_frame locks the model itself
        Layers L = engine.render_frame(t);
        ub.push_back(L.uv_bg);
        if (L.uv_fg.defined() && L.alpha.defined()) {
            uf.push_back(L.uv_fg);
            al.push_back(L.alpha);
        }
    }
    torch::Tensor abg, afg, gamma;
    int64_t step;
    {
        std::lock_guard<std::mutex> lock(engine.model_mutex());
        abg = engine.model().atlas_bg();
        afg = engine.model().atlas_fg();
        gamma = engine.model().parallax_bg();  // a moving camera's plane + parallax, if fitted
        step = engine.snapshot().step;
    }
    const bool two = afg.defined() && int(uf.size()) == data.frames;
    DepthModel m =
        fit_depth(data.radius, torch::cat(ub), two ? torch::cat(uf) : torch::Tensor(),
                  two ? torch::cat(al) : torch::Tensor(), int(abg.size(1)), int(abg.size(2)),
                  two ? int(afg.size(1)) : 0, two ? int(afg.size(2)) : 0, opts, gamma);
    m.fit_step = step;
    return m;
}

DepthModel project_depth(FitEngine& engine, const fs::path& project_dir, bool* built) {
    const fs::path dir = depth_dir(project_dir);
    if (built) *built = false;
    if (DepthModel::exists(dir)) {
        DepthModel m = DepthModel::load(dir);
        if (m.fit_step == engine.snapshot().step && m.frames() == engine.data().frames) return m;
    }
    DepthModel m = build_depth(engine);
    m.save(dir);
    if (built) *built = true;
    return m;
}

}  // namespace refocus
