#include "prepare/noise.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "project/project.h"
#include "util/error.h"

namespace refocus {

namespace {

constexpr int kMinCells = 64;
// The share of cells kept: those whose neighbourhood of cell means is flattest.
constexpr double kFlatShare = 0.15;
// |HH| of a Gaussian of σ, averaged over its lowest 95 %: σ · √(2/π) · (1 − e^(−1.96²/2)) / 0.95.
constexpr double kTrimmedMeanAbs = 0.7169;

double quantile(std::vector<float>& v, double q) {
    const size_t k = std::min(v.size() - 1, size_t(q * double(v.size())));
    std::nth_element(v.begin(), v.begin() + k, v.end());
    return v[k];
}

}  // namespace

std::array<double, 3> frame_noise_levels(const Image& linear, double rounding_var) {
    std::array<double, 3> out{{-1, -1, -1}};
    const int W = linear.width, H = linear.height, C = linear.channels;
    const int cw = W / 2, ch = H / 2;
    if (C < 1 || cw < 3 || ch < 3) return out;
    std::vector<float> v(size_t(W) * H), ll(size_t(cw) * ch), hh(size_t(cw) * ch);
    std::vector<unsigned char> clipped(size_t(cw) * ch);
    for (int c = 0; c < 3; ++c) {
        const int src = std::min(c, C - 1);
        for (size_t p = 0; p < v.size(); ++p)
            v[p] = 255.0f * linear_to_srgb(linear.pixels[p * C + src]);
        for (int y = 0; y < ch; ++y) {
            for (int x = 0; x < cw; ++x) {
                const float* r0 = &v[size_t(2 * y) * W + 2 * x];
                const float* r1 = r0 + W;
                const float a = r0[0], b = r0[1], cc = r1[0], d = r1[1];
                const size_t i = size_t(y) * cw + x;
                ll[i] = 0.5f * (a + b + cc + d);
                hh[i] = 0.5f * (a - b - cc + d);
                const float lo = std::min(std::min(a, b), std::min(cc, d));
                const float hi = std::max(std::max(a, b), std::max(cc, d));
                clipped[i] = lo <= 0.5f || hi >= 254.5f;
            }
        }
        // Flatness from the neighbouring cells' means only: under white noise they are
        // independent of this cell's HH, so choosing flat cells does not choose small noise.
        std::vector<float> act, keep_hh;
        std::vector<size_t> idx;
        act.reserve(size_t(cw) * ch);
        idx.reserve(size_t(cw) * ch);
        for (int y = 1; y + 1 < ch; ++y) {
            for (int x = 1; x + 1 < cw; ++x) {
                const size_t i = size_t(y) * cw + x;
                if (clipped[i] || clipped[i - 1] || clipped[i + 1] || clipped[i - cw] ||
                    clipped[i + cw])
                    continue;
                act.push_back(std::abs(ll[i + 1] - ll[i - 1]) + std::abs(ll[i + cw] - ll[i - cw]));
                idx.push_back(i);
            }
        }
        if (act.size() < size_t(kMinCells) / kFlatShare) continue;
        std::vector<float> sorted = act;
        const double limit = quantile(sorted, kFlatShare);
        keep_hh.reserve(act.size());
        for (size_t k = 0; k < act.size(); ++k)
            if (act[k] <= limit) keep_hh.push_back(std::abs(hh[idx[k]]));
        if (keep_hh.size() < size_t(kMinCells)) continue;
        std::vector<float> s = keep_hh;
        const double cut = quantile(s, 0.95);
        double sum = 0;
        size_t n = 0;
        for (float e : keep_hh)
            if (e <= cut) sum += e, ++n;
        const double sigma = n > 0 ? sum / double(n) / kTrimmedMeanAbs : 0.0;
        out[c] = std::sqrt(std::max(0.0, sigma * sigma - rounding_var));
    }
    return out;
}

double source_rounding_var(const std::string& source_format) {
    if (source_format == "uint8") return 1.0 / 12.0;
    if (source_format == "uint16") return 1.0 / 12.0 / (257.0 * 257.0);
    return 0.0;
}

NoiseEstimate combine_frame_noise(const std::vector<std::array<double, 3>>& per_frame) {
    NoiseEstimate e;
    for (int c = 0; c < 3; ++c) {
        std::vector<double> v;
        for (const auto& f : per_frame)
            if (f[c] >= 0) v.push_back(f[c]);
        if (v.empty()) return NoiseEstimate{};
        // The least, not the median: the sensor's noise is in every frame, while texture
        // brought into focus adds to a frame's reading (synth tripod's sharp frames read 12-16
        // levels, its blurred ones under 0.3), so the cleanest frame says most.
        e.sigma[c] = *std::min_element(v.begin(), v.end());
        e.frames = int(v.size());
    }
    return e;
}

std::vector<int> noise_sample_frames(int frames) {
    std::vector<int> out;
    const int n = std::min(frames, 9);
    for (int k = 0; k < n; ++k) {
        const int t = n == 1 ? 0 : int(std::lround(double(k) * (frames - 1) / (n - 1)));
        if (out.empty() || out.back() != t) out.push_back(t);
    }
    return out;
}

std::string NoiseEstimate::describe() const {
    if (!measured()) return "not measured";
    char buf[160];
    std::snprintf(buf, sizeof buf, "sigma %.2f levels (R %.2f, G %.2f, B %.2f; %d frames)", mean(),
                  sigma[0], sigma[1], sigma[2], frames);
    return buf;
}

nlohmann::json NoiseEstimate::to_json() const {
    return {{"sigma_levels", {sigma[0], sigma[1], sigma[2]}}, {"frames", frames}};
}

NoiseEstimate NoiseEstimate::from_json(const nlohmann::json& j, const std::string& label) {
    auto bad = [&](const std::string& why) {
        return Error(file_error(
            label, "\"noise\" " + why + " (remove the \"noise\" entry to measure it again)"));
    };
    if (!j.is_object()) throw bad("must be an object");
    NoiseEstimate e;
    const auto s = j.find("sigma_levels");
    if (s == j.end() || !s->is_array() || s->size() != 3)
        throw bad("needs sigma_levels: 3 numbers");
    for (int c = 0; c < 3; ++c) {
        if (!(*s)[c].is_number()) throw bad("sigma_levels must be numbers");
        const double v = (*s)[c].get<double>();
        if (!(v >= 0 && v <= 255)) throw bad("sigma_levels must lie in 0..255");
        e.sigma[c] = v;
    }
    const auto f = j.find("frames");
    if (f == j.end() || !f->is_number_integer() || f->get<long long>() < 1 ||
        f->get<long long>() > 1000000)
        throw bad("needs frames: a count of at least 1");
    e.frames = f->get<int>();
    return e;
}

NoiseEstimate measure_project_noise(const Project& p) {
    const double q = source_rounding_var(p.source_format);
    std::vector<std::array<double, 3>> per;
    for (int t : noise_sample_frames(p.frames))
        per.push_back(frame_noise_levels(p.read_frame(t), q));
    return combine_frame_noise(per);
}

NoiseEstimate project_noise(const Project& p) {
    const auto it = p.sections.find("noise");
    if (it != p.sections.end()) return NoiseEstimate::from_json(*it, p.project_file().string());
    return measure_project_noise(p);
}

}  // namespace refocus
