#include "prepare/coc.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <tuple>

#include "prepare/detail.h"
#include "util/error.h"

namespace refocus {

using namespace prep_detail;

namespace {

int reblur_ksize(double sigma0) {
    return 2 * int(std::ceil(4.0 * sigma0)) + 1;
}

// Edge step response (the integral of the line-spread function) at offset u from the edge.
double step_response(double u, double r, CocPsf psf) {
    if (psf == CocPsf::Gaussian) {
        const double s = r / 2.0;  // equal-variance disk: σ = r/2
        if (s < 1e-9) return u > 0 ? 1.0 : (u < 0 ? 0.0 : 0.5);
        return 0.5 * (1.0 + std::erf(u / (s * std::sqrt(2.0))));
    }
    if (r < 1e-9) return u > 0 ? 1.0 : (u < 0 ? 0.0 : 0.5);
    if (u <= -r) return 0.0;
    if (u >= r) return 1.0;
    // Area of the unit-area disk left of a chord at distance u from the centre.
    return 0.5 + (u * std::sqrt(r * r - u * u) + r * r * std::asin(u / r)) / (M_PI * r * r);
}

// The estimator's σ on an ideal pixel-integrated edge of radius r: averaged over sub-pixel
// positions of the edge. Derivative = central difference (Sobel's along-gradient profile),
// reblur = the same discrete Gaussian kernel estimate_coc uses.
void convolve1d(std::vector<double>& s, double sigma) {
    if (sigma <= 0) return;
    const cv::Mat k = cv::getGaussianKernel(reblur_ksize(sigma), sigma, CV_64F);
    const int kh = k.rows / 2, n = int(s.size());
    std::vector<double> o(n, 0.0);
    for (int i = 0; i < n; ++i)
        for (int j = -kh; j <= kh; ++j)
            o[i] += k.at<double>(j + kh) * s[std::clamp(i + j, 0, n - 1)];
    s.swap(o);
}

double simulate_sigma(double r, CocPsf psf, double sigma0, double presmooth) {
    const int n = 2 * int(std::ceil(r + 6 * sigma0 + 6 * presmooth + 8)) + 1;
    double acc = 0;
    int count = 0;
    for (int oi = 0; oi < 8; ++oi) {
        const double c = n / 2 + oi / 8.0;
        std::vector<double> s(n), s1;
        for (int i = 0; i < n; ++i) {
            double v = 0;  // integrate over the pixel's extent (8 sub-samples)
            for (int j = 0; j < 8; ++j) v += step_response(i - 0.5 + (j + 0.5) / 8.0 - c, r, psf);
            s[i] = v / 8.0;
        }
        convolve1d(s, presmooth);
        s1 = s;
        convolve1d(s1, sigma0);
        int best = 1;
        double gbest = -1;
        for (int i = 1; i + 1 < n; ++i) {
            const double g = 0.5 * (s[i + 1] - s[i - 1]);
            if (g > gbest) gbest = g, best = i;
        }
        const double g1 = 0.5 * (s1[best + 1] - s1[best - 1]);
        const double R = gbest / g1;
        if (R > 1.0 + 1e-9) {
            acc += sigma0 / std::sqrt(R * R - 1.0);
            ++count;
        }
    }
    return count ? acc / count : 1e9;
}

struct Table {
    double step = 0.05;
    std::vector<double> sigma;  // sigma[i] = measured σ for r = i·step, made non-decreasing
};

const Table& calibration(CocPsf psf, double sigma0, double presmooth) {
    static std::mutex mu;
    static std::map<std::tuple<int, long, long>, Table> cache;
    std::lock_guard<std::mutex> lock(mu);
    const auto key =
        std::make_tuple(int(psf), std::lround(sigma0 * 1e6), std::lround(presmooth * 1e6));
    auto it = cache.find(key);
    if (it != cache.end()) return it->second;
    Table t;
    const double rtop = 48.0;
    for (double r = 0; r <= rtop + 1e-9; r += t.step) {
        double s = simulate_sigma(r, psf, sigma0, presmooth);
        if (!t.sigma.empty()) s = std::max(s, t.sigma.back());
        t.sigma.push_back(s);
    }
    return cache.emplace(key, std::move(t)).first->second;
}

}  // namespace

double sigma_of_coc(double r, CocPsf psf, double sigma0, double presmooth) {
    return simulate_sigma(r, psf, sigma0, presmooth);
}

double coc_from_sigma(double sigma_est, CocPsf psf, double sigma0, double presmooth) {
    const Table& t = calibration(psf, sigma0, presmooth);
    if (!(sigma_est > t.sigma.front())) return 0.0;
    if (sigma_est >= t.sigma.back()) return (t.sigma.size() - 1) * t.step;
    const size_t i = std::upper_bound(t.sigma.begin(), t.sigma.end(), sigma_est) - t.sigma.begin();
    const double a = t.sigma[i - 1], b = t.sigma[i];
    const double f = b > a ? (sigma_est - a) / (b - a) : 0.0;
    return (i - 1 + f) * t.step;
}

Image estimate_coc_at_edges(const Image& frame, const CocOptions& o, Image& weight) {
    if (frame.empty()) throw Error("estimate_coc: empty frame");
    if (!(o.sigma0 > 0)) throw Error("estimate_coc: sigma0 must be > 0");
    const int w = frame.width, h = frame.height;
    cv::Mat L = linear_grey(frame);
    if (o.presmooth > 0) {
        const int kp = reblur_ksize(o.presmooth);
        cv::GaussianBlur(L, L, cv::Size(kp, kp), o.presmooth, o.presmooth, cv::BORDER_REPLICATE);
    }
    cv::Mat gx, gy, L1, gx1, gy1;
    // Sobel/8: central difference across the edge, [1 2 1]/4 smoothing along it.
    cv::Sobel(L, gx, CV_32F, 1, 0, 3, 1.0 / 8.0, 0, cv::BORDER_REPLICATE);
    cv::Sobel(L, gy, CV_32F, 0, 1, 3, 1.0 / 8.0, 0, cv::BORDER_REPLICATE);
    const int ks = reblur_ksize(o.sigma0);
    cv::GaussianBlur(L, L1, cv::Size(ks, ks), o.sigma0, o.sigma0, cv::BORDER_REPLICATE);
    cv::Sobel(L1, gx1, CV_32F, 1, 0, 3, 1.0 / 8.0, 0, cv::BORDER_REPLICATE);
    cv::Sobel(L1, gy1, CV_32F, 0, 1, 3, 1.0 / 8.0, 0, cv::BORDER_REPLICATE);
    cv::Mat mag, mag1;
    cv::magnitude(gx, gy, mag);
    cv::magnitude(gx1, gy1, mag1);

    // Edge threshold: an absolute floor and a multiple of the median gradient (noise level).
    std::vector<float> mv(mag.begin<float>(), mag.end<float>());
    std::nth_element(mv.begin(), mv.begin() + mv.size() / 2, mv.end());
    const double high = std::max(o.min_edge_gradient, o.edge_median_factor * mv[mv.size() / 2]);
    // Canny (non-maximum suppression + hysteresis) on the linear-light derivatives, so that the
    // edge pixel is the gradient peak the ratio model assumes.
    double gmax = 0;
    cv::minMaxLoc(mag, nullptr, &gmax);
    const double scale = gmax > 0 ? 16000.0 / gmax : 1.0;
    cv::Mat dx16, dy16, edges;
    gx.convertTo(dx16, CV_16S, scale);
    gy.convertTo(dy16, CV_16S, scale);
    cv::Canny(dx16, dy16, edges, 0.5 * high * scale, high * scale, true);

    Image sparse(w, h, 1, 0.0f);
    weight = Image(w, h, 1, 0.0f);
    const int border = 2;
    for (int y = border; y < h - border; ++y)
        for (int x = border; x < w - border; ++x) {
            if (!edges.at<unsigned char>(y, x)) continue;
            const double g = mag.at<float>(y, x), g1 = mag1.at<float>(y, x);
            if (g1 <= 0) continue;
            const double R = g / g1;
            // R ≤ 1 cannot come from a lone blurred edge (reblurring never steepens it): it is
            // a corner, a thin line or a neighbour's interference. Such samples are dropped, not
            // read as "infinitely blurred" (which would give a sharp frame huge radii at corners).
            if (R <= 1.0 + 1e-6) continue;
            const double r =
                coc_from_sigma(o.sigma0 / std::sqrt(R * R - 1.0), o.psf, o.sigma0, o.presmooth);
            sparse.at(x, y, 0) = float(std::min(r, o.rmax));
            weight.at(x, y, 0) = 1.0f;
        }
    return sparse;
}

Image weighted_guided_filter(const Image& guide, const Image& src, const Image& weight, int radius,
                             double eps, Image* coverage) {
    if (guide.channels != 1 || src.channels != 1 || weight.channels != 1 ||
        !guide.same_shape(src) || !guide.same_shape(weight))
        throw Error("weighted_guided_filter: need 1-channel images of one size");
    const cv::Size win(2 * radius + 1, 2 * radius + 1);
    auto box = [&](const cv::Mat& m) {
        cv::Mat r;
        cv::boxFilter(m, r, CV_32F, win, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
        return r;
    };
    const cv::Mat I = as_mat(guide), p = as_mat(src), wt = as_mat(weight);
    const cv::Mat W = box(wt);
    const cv::Mat mI = box(wt.mul(I)), mP = box(wt.mul(p)), mII = box(wt.mul(I.mul(I))),
                  mIP = box(wt.mul(I.mul(p)));
    cv::Mat a(I.size(), CV_32F, 0.0f), b(I.size(), CV_32F, 0.0f);
    const float tiny = 1e-6f;
    for (int y = 0; y < I.rows; ++y)
        for (int x = 0; x < I.cols; ++x) {
            const float c = W.at<float>(y, x);
            if (c < tiny) continue;
            const float ui = mI.at<float>(y, x) / c, up = mP.at<float>(y, x) / c;
            const float var = std::max(0.0f, mII.at<float>(y, x) / c - ui * ui);
            const float cov = mIP.at<float>(y, x) / c - ui * up;
            const float ak = cov / (var + float(eps));
            a.at<float>(y, x) = ak;
            b.at<float>(y, x) = up - ak * ui;
        }
    // Average the windows' linear models, each weighted by its confidence W — only the windows
    // that have a model: counting the skipped ones (W < tiny) in C as well gave q = 0 wherever
    // only such windows reached a pixel (lines of radius 0 along the edge of the measured area,
    // which the fit deconvolved into dark streaks on the sample).
    cv::Mat Wm;
    cv::threshold(W, Wm, tiny, 0.0, cv::THRESH_TOZERO);
    const cv::Mat C = box(Wm), A = box(Wm.mul(a)), B = box(Wm.mul(b));
    Image q(guide.width, guide.height, 1, 0.0f);
    if (coverage) *coverage = Image(guide.width, guide.height, 1, 0.0f);
    for (int y = 0; y < I.rows; ++y)
        for (int x = 0; x < I.cols; ++x) {
            const float c = C.at<float>(y, x);
            if (coverage) coverage->at(x, y, 0) = c;
            if (c < tiny * tiny) continue;
            q.at(x, y, 0) = (A.at<float>(y, x) * I.at<float>(y, x) + B.at<float>(y, x)) / c;
        }
    return q;
}

Image estimate_coc(const Image& frame, const CocOptions& o) {
    Image weight;
    const Image sparse = estimate_coc_at_edges(frame, o, weight);
    const int w = frame.width, h = frame.height;
    Image dense(w, h, 1, 0.0f);
    std::vector<float> samples;
    for (size_t i = 0; i < sparse.pixels.size(); ++i)
        if (weight.pixels[i] > 0) samples.push_back(sparse.pixels[i]);
    if (samples.empty()) return dense;  // no edges: nothing to measure, call it sharp
    std::nth_element(samples.begin(), samples.begin() + samples.size() / 2, samples.end());
    const float global = samples[samples.size() / 2];

    // Guide: sRGB-encoded grey, where equal steps look equally strong.
    cv::Mat g8 = srgb_grey8(frame);
    Image guide(w, h, 1);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) guide.at(x, y, 0) = g8.at<unsigned char>(y, x) / 255.0f;

    // Coarse to fine fill: the finest window that has edge samples decides; where none is
    // near, a 3x and then 9x larger window; finally the frame's median.
    int r0 = o.guide_radius > 0 ? o.guide_radius : std::max(4, std::min(w, h) / 10);
    std::vector<char> done(size_t(w) * h, 0);
    for (int level = 0; level < 3; ++level) {
        const int r = r0 * (level == 0 ? 1 : level == 1 ? 3 : 9);
        Image cov;
        const Image q = weighted_guided_filter(guide, sparse, weight, r, o.guide_eps, &cov);
        // Coverage of a pixel = mean over its windows of each window's mean weight; require
        // about 2 edge pixels per window.
        const float need = 2.0f / float((2 * r + 1) * (2 * r + 1));
        for (size_t i = 0; i < done.size(); ++i)
            if (!done[i] && cov.pixels[i] >= need) {
                dense.pixels[i] = q.pixels[i];
                done[i] = 1;
            }
    }
    for (size_t i = 0; i < done.size(); ++i) {
        if (!done[i]) dense.pixels[i] = global;
        dense.pixels[i] = std::clamp(dense.pixels[i], 0.0f, float(o.rmax));
    }
    return dense;
}

std::vector<Image> smooth_coc_temporally(const std::vector<Image>& coc, const ClipFlow& flow) {
    const int n = int(coc.size());
    std::vector<Image> out;
    for (int t = 0; t < n; ++t) {
        const Image& c = coc[t];
        Image s(c.width, c.height, 1);
        const bool has_next = t + 1 < n && size_t(t) < flow.fwd.size();
        const bool has_prev = t > 0 && size_t(t - 1) < flow.bwd.size();
        const cv::Mat next = has_next ? as_mat(coc[t + 1]) : cv::Mat();
        const cv::Mat prev = has_prev ? as_mat(coc[t - 1]) : cv::Mat();
        for (int y = 0; y < c.height; ++y)
            for (int x = 0; x < c.width; ++x) {
                float sum = 2.0f * c.at(x, y, 0), wsum = 2.0f;
                if (has_next && flow.fwd_valid[t].at(x, y, 0) > 0.5f) {
                    sum += sample1(next, x + flow.fwd[t].at(x, y, 0), y + flow.fwd[t].at(x, y, 1));
                    wsum += 1.0f;
                }
                if (has_prev && flow.bwd_valid[t - 1].at(x, y, 0) > 0.5f) {
                    sum += sample1(prev, x + flow.bwd[t - 1].at(x, y, 0),
                                   y + flow.bwd[t - 1].at(x, y, 1));
                    wsum += 1.0f;
                }
                s.at(x, y, 0) = sum / wsum;
            }
        out.push_back(std::move(s));
    }
    return out;
}

}  // namespace refocus
