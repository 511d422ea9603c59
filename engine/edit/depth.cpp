// Inverse depth from the fit's radius maps (seed 001 eq. 1.12 with A = 1); see depth.h.
#include "edit/depth.h"

#include <torch/torch.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>

#include "fit/fit_engine.h"
#include "io/image_file.h"
#include "util/error.h"

namespace refocus {

namespace {

using nlohmann::json;

// One term w·(r − |z − a|)² of a 1-D problem.
struct Obs {
    double a, r, w;
};

// Exact  argmin_z Σ w_i (r_i − |z − a_i|)²  (see depth.h). Between sorted breakpoints the signs
// s_i = sign(z − a_i) are fixed and the cost is Σ w_i (z − (a_i + s_i·r_i))², minimised by a
// clamped weighted mean. `best` is the global minimum; lo/hi the smallest and largest minimiser
// whose cost is within tie·Σw of it (hi − lo large: the side of the focal plane is ambiguous).
// `obs` is reordered. All NaN when there is no weight.
struct Solution {
    double best, lo, hi;
    bool ambiguous(double gap = 0.5) const { return hi - lo > gap; }
};

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
        if (c.cost <= best + tie * W) sol.lo = std::min(sol.lo, c.z), sol.hi = std::max(sol.hi, c.z);
    return sol;
}

// Bilinear sample of a 1-channel atlas at (u, v) ∈ [−1, 1]² (render/preview.h convention).
inline float sample1(const Image& atlas, float u, float v) {
    int x0, x1, y0, y1;
    float fx, fy;
    preview_atlas_coord(u, atlas.width, x0, x1, fx);
    preview_atlas_coord(v, atlas.height, y0, y1, fy);
    const float top = atlas.at(x0, y0, 0) * (1 - fx) + atlas.at(x1, y0, 0) * fx;
    const float bot = atlas.at(x0, y1, 0) * (1 - fx) + atlas.at(x1, y1, 0) * fx;
    return top * (1 - fy) + bot * fy;
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

// One atlas layer during the fit: texel depths and the frames' observations of each texel.
struct LayerFit {
    int W = 0, H = 0;
    std::vector<float> d;                 // [H·W] inverse depth
    std::vector<float> seen;              // [H·W] total splat weight
    std::vector<int> start;               // CSR offsets into obs, [H·W + 1]
    struct TexObs {
        int t;
        float w, r;  // splat weight, weighted mean radius
    };
    std::vector<TexObs> obs;              // sorted by texel, then frame
};

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
        auto it = std::lower_bound(b, e, t, [](const LayerFit::TexObs& o, int tt) { return o.t < tt; });
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
            double s = std::isfinite(a) && std::isfinite(b) ? 0.5 * (a + b) : std::isfinite(a) ? a : b;
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
            B[size_t(t) * T + u] = -0.5 * (D[size_t(t) * T + u] * D[size_t(t) * T + u] - row[t] -
                                          col[u] + all);
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

}  // namespace

DepthModel fit_depth(const torch::Tensor& radius_in, const torch::Tensor& uv_bg_in,
                     const torch::Tensor& uv_fg_in, const torch::Tensor& alpha_in, int bg_h,
                     int bg_w, int fg_h, int fg_w, const DepthFitOptions& opts) {
    if (!radius_in.defined() || radius_in.dim() != 3) throw Error("fit_depth: radius must be [T,H,W]");
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
    const float* R = radius.data_ptr<float>();
    const float* UB = uvb.data_ptr<float>();
    const float* UF = two ? uvf.data_ptr<float>() : nullptr;
    const float* AL = two ? alpha.data_ptr<float>() : nullptr;
    const size_t HW = size_t(H) * Wd;

    LayerFit layers[2];
    layers[0].W = bg_w, layers[0].H = bg_h;
    if (two) layers[1].W = fg_w, layers[1].H = fg_h;
    const int nl = two ? 2 : 1;

    // Splat every valid pixel bilinearly onto its layer's texels, aggregated per (texel, frame);
    // keep a strided subset of pixels per frame for the focus/offset updates.
    const int step = std::max(1, int(std::ceil(std::sqrt(double(HW) / std::max(1, opts.focus_samples)))));
    std::vector<std::vector<Px>> px(T);
    {
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
                    const float wts[4] = {(1 - p.fx) * (1 - p.fy), p.fx * (1 - p.fy),
                                          (1 - p.fx) * p.fy, p.fx * p.fy};
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
    }

    std::vector<double> f(T, 0.0), o(T, 0.0);
    std::vector<Obs> buf;
    // Texels: exact per-texel solve. Where the side of the focal plane is ambiguous (seen at one
    // focus only), the side of the confident neighbours (push-pull of the texels the data
    // decided) when they clearly lie on one side, else the rule: background behind, foreground in
    // front.
    std::vector<Solution> sols;
    std::vector<float> confident, ref;
    auto update_texels = [&]() {
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
            ref = L.d;
            if (any_confident) fill_unseen(ref, confident, L.W, L.H);
            for (size_t x = 0; x < n; ++x)
                if (L.seen[x] > 0 && !(confident[x] > 0)) {
                    const Solution& s = sols[x];
                    const double mid = 0.5 * (s.lo + s.hi), off = any_confident ? ref[x] - mid : 0.0;
                    const bool hi = std::fabs(off) > 0.25 * (s.hi - s.lo) ? off > 0 : l == 1;
                    L.d[x] = float(hi ? s.hi : s.lo);
                }
            fill_unseen(L.d, L.seen, L.W, L.H);
        }
    };
    auto depth_px = [&](const Px& p, int t) {
        return sample_px(layers[p.fg], p) + (p.fg ? float(o[t]) : 0.0f);
    };
    auto cost = [&]() {
        double c = 0;
        size_t n = 0;
        for (int t = 0; t < T; ++t)
            for (const Px& p : px[t]) {
                const double e = p.r - std::fabs(depth_px(p, t) - f[t]);
                c += e * e;
                ++n;
            }
        return n ? c / n : 0.0;
    };
    auto update_frames = [&]() {
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
    };
    auto run = [&](const std::vector<double>& f0, int& rounds) {
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
    };

    // Two starts: the MDS focus, and a constant focus (which wins where the focus never moves).
    int rounds_a = 0, rounds_b = 0;
    const std::vector<double> f_mds = initial_focus(layers[0], T);
    const double cost_a = run(f_mds, rounds_a);
    std::vector<double> fa = f, oa = o;
    std::vector<float> da[2] = {layers[0].d, layers[1].d};
    const double cost_b = run(std::vector<double>(T, 0.0), rounds_b);
    if (cost_a <= cost_b) {
        f = fa, o = oa;
        layers[0].d = da[0], layers[1].d = da[1];
    }

    // Global mirror (fg nearer; one layer: most pixels behind the focal plane), then the shift.
    bool mirror = false;
    if (two) {
        std::vector<float> vb, vf;
        for (size_t x = 0; x < layers[0].d.size(); ++x)
            if (layers[0].seen[x] > 0) vb.push_back(layers[0].d[x]);
        double mo = 0;
        for (double x : o) mo += x / T;
        for (size_t x = 0; x < layers[1].d.size(); ++x)
            if (layers[1].seen[x] > 0) vf.push_back(layers[1].d[x] + float(mo));
        if (!vb.empty() && !vf.empty()) mirror = median_of(vf) < median_of(vb);
    } else {
        long behind = 0;
        for (int t = 0; t < T; ++t)
            for (const Px& p : px[t]) behind += depth_px(p, t) < f[t] ? 1 : -1;
        mirror = behind < 0;
    }
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
    m.rounds = cost_a <= cost_b ? rounds_a : rounds_b;

    // rms over every valid pixel, through the same sampling as frame_depth.
    double se = 0;
    size_t n = 0;
    for (int t = 0; t < T; ++t)
        for (size_t i = 0; i < HW; ++i) {
            const size_t k = size_t(t) * HW + i;
            const bool fg = two && AL[k] > 0.5f;
            const float* uv = (fg ? UF : UB) + 2 * k;
            if (!std::isfinite(R[k]) || !std::isfinite(uv[0]) || !std::isfinite(uv[1])) continue;
            const float d = fg ? sample1(m.fg_atlas, uv[0], uv[1]) + m.fg_offset[t]
                               : sample1(m.bg_atlas, uv[0], uv[1]);
            const double e = std::max(R[k], 0.0f) - std::fabs(d - m.focus[t]);
            se += e * e;
            ++n;
        }
    m.rms_px = n ? std::sqrt(se / n) : 0.0;
    return m;
}

// ---------------------------------------------------------------- sampling

namespace {
int clamp_frame(int t, int frames) { return std::clamp(t, 0, std::max(frames - 1, 0)); }

void check_uv(const Image& uv, const char* what) {
    if (uv.channels != 2) throw Error(std::string("depth: the ") + what + " UV map needs 2 channels");
}
}  // namespace

PreviewDepth DepthModel::frame_depth(int t, const Image& uv_bg, const Image& uv_fg) const {
    check_uv(uv_bg, "background");
    PreviewDepth out;
    auto sample = [&](const Image& atlas, const Image& uv, float add) {
        Image img(uv.width, uv.height, 1);
        for (int y = 0; y < uv.height; ++y)
            for (int x = 0; x < uv.width; ++x)
                img.at(x, y, 0) = sample1(atlas, uv.at(x, y, 0), uv.at(x, y, 1)) + add;
        return img;
    };
    out.background = sample(bg_atlas, uv_bg, 0.0f);
    if (has_fg() && !uv_fg.empty()) {
        check_uv(uv_fg, "foreground");
        out.foreground = sample(fg_atlas, uv_fg, fg_offset.empty() ? 0.0f : fg_offset[clamp_frame(t, frames())]);
    }
    return out;
}

float DepthModel::depth_at_atlas(int layer, float u, float v, int t) const {
    if (layer == Foreground && has_fg())
        return sample1(fg_atlas, u, v) + (fg_offset.empty() ? 0.0f : fg_offset[clamp_frame(t, frames())]);
    return sample1(bg_atlas, u, v);
}

float DepthModel::depth_at_pixel(int t, int x, int y, const Image& uv_bg, const Image& uv_fg,
                                 const Image& alpha) const {
    check_uv(uv_bg, "background");
    x = std::clamp(x, 0, uv_bg.width - 1);
    y = std::clamp(y, 0, uv_bg.height - 1);
    if (has_fg() && !alpha.empty() && !uv_fg.empty() && alpha.at(x, y, 0) > 0.5f)
        return depth_at_atlas(Foreground, uv_fg.at(x, y, 0), uv_fg.at(x, y, 1), t);
    return depth_at_atlas(Background, uv_bg.at(x, y, 0), uv_bg.at(x, y, 1), t);
}

Image DepthModel::depth_map(int t, const Image& uv_bg, const Image& uv_fg, const Image& alpha) const {
    check_uv(uv_bg, "background");
    Image out(uv_bg.width, uv_bg.height, 1);
    for (int y = 0; y < out.height; ++y)
        for (int x = 0; x < out.width; ++x) out.at(x, y, 0) = depth_at_pixel(t, x, y, uv_bg, uv_fg, alpha);
    return out;
}

// ---------------------------------------------------------------- files

namespace {
const char* kJson = "depth.json";
const char* kBg = "depth_bg.exr";
const char* kFg = "depth_fg.exr";
}  // namespace

bool DepthModel::exists(const fs::path& dir) { return fs::exists(dir / kJson); }

void DepthModel::save(const fs::path& dir) const {
    if (bg_atlas.empty() || bg_atlas.channels != 1 || focus.empty() || fg_offset.size() != focus.size())
        throw Error(file_error((dir / kJson).string(), "refusing to save an incomplete depth model"));
    std::error_code ec;
    fs::create_directories(dir, ec);
    write_image_file((dir / kBg).string(), bg_atlas, PixelFormat::ExrFloat, false);
    if (has_fg()) write_image_file((dir / kFg).string(), fg_atlas, PixelFormat::ExrFloat, false);
    json j = {{"version", kVersion},
              {"frames", frames()},
              {"bg", {{"file", kBg}, {"width", bg_atlas.width}, {"height", bg_atlas.height}}},
              {"fg", nullptr},
              {"focus", focus},
              {"fg_offset", fg_offset},
              {"rms_px", rms_px},
              {"rounds", rounds},
              {"fit_step", fit_step},
              {"units", "inverse depth in px of blur radius at the clip's aperture (seed 001 eq. 1.12, A = 1)"}};
    if (has_fg()) j["fg"] = {{"file", kFg}, {"width", fg_atlas.width}, {"height", fg_atlas.height}};
    write_file_atomic(dir / kJson, j.dump(2) + "\n");  // last: the model is complete when it exists
    if (!has_fg()) fs::remove(dir / kFg, ec);
}

DepthModel DepthModel::load(const fs::path& dir) {
    const std::string jpath = (dir / kJson).string();
    if (!fs::exists(jpath)) throw Error(file_error(jpath, "no depth model here (missing file)"));
    json j;
    try {
        j = json::parse(read_text_file(jpath));
    } catch (const json::exception& e) {
        throw Error(file_error(jpath, std::string("not valid JSON: ") + e.what()));
    }
    auto bad = [&](const std::string& what) { throw Error(file_error(jpath, what)); };
    DepthModel m;
    auto floats = [&](const char* key, size_t n) {
        if (!j.contains(key) || !j[key].is_array() || j[key].size() != n)
            bad(std::string("'") + key + "' must be an array of " + std::to_string(n) + " numbers");
        std::vector<float> v;
        for (const json& x : j[key]) {
            if (!x.is_number() || !std::isfinite(x.get<double>()))
                bad(std::string("'") + key + "' holds a non-finite or non-numeric value");
            v.push_back(x.get<float>());
        }
        return v;
    };
    auto atlas = [&](const char* key, const char* file) {
        const json& a = j[key];
        if (!a.is_object() || !a.contains("width") || !a.contains("height") ||
            !a["width"].is_number_integer() || !a["height"].is_number_integer() ||
            a["width"].get<int>() < 1 || a["height"].get<int>() < 1)
            bad(std::string("'") + key + "' must hold a positive integer width and height");
        const std::string path = (dir / file).string();
        Image img = read_image_file(path, false, NonFinitePolicy::Reject).image;
        if (img.channels != 1 || img.width != a["width"].get<int>() || img.height != a["height"].get<int>())
            throw Error(file_error(path, "is " + std::to_string(img.width) + "x" +
                                             std::to_string(img.height) + "x" +
                                             std::to_string(img.channels) + ", " + kJson + " says " +
                                             std::to_string(a["width"].get<int>()) + "x" +
                                             std::to_string(a["height"].get<int>()) + "x1"));
        return img;
    };
    try {
        if (!j.is_object() || !j.contains("version") || !j["version"].is_number_integer())
            bad("'version' is missing");
        const int version = j["version"].get<int>();
        if (version > kVersion || version < 1)
            bad("version " + std::to_string(version) + " (this Refocus reads depth version " +
                std::to_string(kVersion) + ")");
        if (!j.contains("frames") || !j["frames"].is_number_integer() || j["frames"].get<int>() < 1)
            bad("'frames' must be a positive integer");
        const size_t n = j["frames"].get<size_t>();
        m.focus = floats("focus", n);
        m.fg_offset = floats("fg_offset", n);
        if (!j.contains("bg")) bad("'bg' is missing");
        m.bg_atlas = atlas("bg", kBg);
        if (j.contains("fg") && !j["fg"].is_null()) m.fg_atlas = atlas("fg", kFg);
        m.rms_px = j.value("rms_px", 0.0);
        m.rounds = j.value("rounds", 0);
        m.fit_step = j.value("fit_step", int64_t(-1));
    } catch (const json::exception& e) {
        bad(std::string("malformed: ") + e.what());
    }
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
    torch::Tensor abg, afg;
    int64_t step;
    {
        std::lock_guard<std::mutex> lock(engine.model_mutex());
        abg = engine.model().atlas_bg();
        afg = engine.model().atlas_fg();
        step = engine.snapshot().step;
    }
    const bool two = afg.defined() && int(uf.size()) == data.frames;
    DepthModel m = fit_depth(data.radius, torch::cat(ub), two ? torch::cat(uf) : torch::Tensor(),
                             two ? torch::cat(al) : torch::Tensor(), int(abg.size(1)),
                             int(abg.size(2)), two ? int(afg.size(1)) : 0,
                             two ? int(afg.size(2)) : 0, opts);
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
