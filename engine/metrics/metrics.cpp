#include "metrics/metrics.h"

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "util/error.h"

namespace refocus {

namespace {

constexpr double kPsnrCap = 100.0;

void check_same(const Image& a, const Image& b, const char* what) {
    if (!a.same_shape(b) || a.empty())
        throw Error(std::string(what) + ": images differ in shape (" + std::to_string(a.width) +
                    "x" + std::to_string(a.height) + "x" + std::to_string(a.channels) + " vs " +
                    std::to_string(b.width) + "x" + std::to_string(b.height) + "x" +
                    std::to_string(b.channels) + ")");
}

double peak_of(MetricSpace s) {
    return s == MetricSpace::Srgb8 ? 255.0 : 1.0;
}

// One channel as a double plane.
std::vector<double> plane(const Image& img, int c) {
    std::vector<double> p(static_cast<size_t>(img.width) * img.height);
    for (size_t i = 0; i < p.size(); ++i) p[i] = img.pixels[i * img.channels + c];
    return p;
}

// Separable "valid" correlation with a 1-D kernel.
std::vector<double> filter_valid(const std::vector<double>& src, int w, int h,
                                 const std::vector<double>& k, int* ow, int* oh) {
    const int n = static_cast<int>(k.size());
    const int w1 = w - n + 1, h1 = h - n + 1;
    std::vector<double> tmp(static_cast<size_t>(w1) * h), out(static_cast<size_t>(w1) * h1);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w1; ++x) {
            double s = 0;
            for (int i = 0; i < n; ++i) s += k[i] * src[static_cast<size_t>(y) * w + x + i];
            tmp[static_cast<size_t>(y) * w1 + x] = s;
        }
    for (int y = 0; y < h1; ++y)
        for (int x = 0; x < w1; ++x) {
            double s = 0;
            for (int i = 0; i < n; ++i) s += k[i] * tmp[static_cast<size_t>(y + i) * w1 + x];
            out[static_cast<size_t>(y) * w1 + x] = s;
        }
    *ow = w1;
    *oh = h1;
    return out;
}

const std::vector<double>& gauss_window() {
    static const std::vector<double> k = [] {
        std::vector<double> g(11);
        double s = 0;
        for (int i = 0; i < 11; ++i) {
            double d = i - 5;
            g[i] = std::exp(-d * d / (2 * 1.5 * 1.5));
            s += g[i];
        }
        for (double& v : g) v /= s;
        return g;
    }();
    return k;
}

// Mean SSIM and mean contrast-structure term (cs) of one plane pair.
void ssim_plane(const std::vector<double>& a, const std::vector<double>& b, int w, int h,
                double peak, double* ssim_out, double* cs_out) {
    const auto& k = gauss_window();
    if (w < 11 || h < 11) throw Error("SSIM needs images of at least 11x11 pixels");
    const double c1 = (0.01 * peak) * (0.01 * peak), c2 = (0.03 * peak) * (0.03 * peak);
    std::vector<double> aa(a.size()), bb(a.size()), ab(a.size());
    for (size_t i = 0; i < a.size(); ++i) {
        aa[i] = a[i] * a[i];
        bb[i] = b[i] * b[i];
        ab[i] = a[i] * b[i];
    }
    int ow, oh;
    auto mu_a = filter_valid(a, w, h, k, &ow, &oh);
    auto mu_b = filter_valid(b, w, h, k, &ow, &oh);
    auto s_aa = filter_valid(aa, w, h, k, &ow, &oh);
    auto s_bb = filter_valid(bb, w, h, k, &ow, &oh);
    auto s_ab = filter_valid(ab, w, h, k, &ow, &oh);
    double sum_ssim = 0, sum_cs = 0;
    for (size_t i = 0; i < mu_a.size(); ++i) {
        double ma = mu_a[i], mb = mu_b[i];
        double va = s_aa[i] - ma * ma, vb = s_bb[i] - mb * mb, cov = s_ab[i] - ma * mb;
        double cs = (2 * cov + c2) / (va + vb + c2);
        double l = (2 * ma * mb + c1) / (ma * ma + mb * mb + c1);
        sum_ssim += l * cs;
        sum_cs += cs;
    }
    *ssim_out = sum_ssim / mu_a.size();
    *cs_out = sum_cs / mu_a.size();
}

std::vector<double> downsample2(const std::vector<double>& p, int w, int h, int* ow, int* oh) {
    *ow = w / 2;
    *oh = h / 2;
    std::vector<double> out(static_cast<size_t>(*ow) * *oh);
    for (int y = 0; y < *oh; ++y)
        for (int x = 0; x < *ow; ++x)
            out[static_cast<size_t>(y) * *ow + x] =
                0.25 * (p[(2 * y) * w + 2 * x] + p[(2 * y) * w + 2 * x + 1] +
                        p[(2 * y + 1) * w + 2 * x] + p[(2 * y + 1) * w + 2 * x + 1]);
    return out;
}

}  // namespace

Image to_metric_space(const Image& linear, MetricSpace space) {
    Image out(linear.width, linear.height, linear.channels);
    for (size_t i = 0; i < out.size(); ++i) {
        float v = linear.pixels[i];
        out.pixels[i] = space == MetricSpace::Srgb8 ? static_cast<float>(linear_to_srgb8(v))
                                                    : (std::isfinite(v) ? v : 0.0f);
    }
    return out;
}

double mse(const Image& a, const Image& b) {
    check_same(a, b, "MSE");
    double s = 0;
    for (size_t i = 0; i < a.size(); ++i) {
        double d = double(a.pixels[i]) - b.pixels[i];
        s += d * d;
    }
    return s / a.size();
}

double psnr_from_mse(double m, double peak) {
    if (m <= 0) return kPsnrCap;
    return std::min(kPsnrCap, 10.0 * std::log10(peak * peak / m));
}

double ssim_raw(const Image& a, const Image& b, double peak) {
    check_same(a, b, "SSIM");
    double total = 0;
    for (int c = 0; c < a.channels; ++c) {
        double s, cs;
        ssim_plane(plane(a, c), plane(b, c), a.width, a.height, peak, &s, &cs);
        total += s;
    }
    return total / a.channels;
}

double ms_ssim_raw(const Image& a, const Image& b, double peak, int* scales_used) {
    check_same(a, b, "MS-SSIM");
    static const double kWeights[5] = {0.0448, 0.2856, 0.3001, 0.2363, 0.1333};
    int scales = 5;
    while (scales > 1 && std::min(a.width, a.height) >> (scales - 1) < 11) --scales;
    double wsum = 0;
    for (int i = 0; i < scales; ++i) wsum += kWeights[i];
    if (scales_used) *scales_used = scales;
    double total = 0;
    for (int c = 0; c < a.channels; ++c) {
        auto pa = plane(a, c), pb = plane(b, c);
        int w = a.width, h = a.height;
        double prod = 1.0;
        for (int s = 0; s < scales; ++s) {
            double ss, cs;
            ssim_plane(pa, pb, w, h, peak, &ss, &cs);
            double term = (s == scales - 1) ? ss : cs;
            // Negative cs (anti-correlated structure) would make the power undefined.
            prod *= std::pow(std::max(term, 0.0), kWeights[s] / wsum);
            if (s + 1 < scales) {
                int nw, nh;
                pa = downsample2(pa, w, h, &nw, &nh);
                pb = downsample2(pb, w, h, &nw, &nh);
                w = nw;
                h = nh;
            }
        }
        total += prod;
    }
    return total / a.channels;
}

double psnr(const Image& pred, const Image& gt, MetricSpace space) {
    check_same(pred, gt, "PSNR");
    return psnr_from_mse(mse(to_metric_space(pred, space), to_metric_space(gt, space)),
                         peak_of(space));
}

double ssim(const Image& pred, const Image& gt, MetricSpace space) {
    return ssim_raw(to_metric_space(pred, space), to_metric_space(gt, space), peak_of(space));
}

double ms_ssim(const Image& pred, const Image& gt, MetricSpace space) {
    return ms_ssim_raw(to_metric_space(pred, space), to_metric_space(gt, space), peak_of(space));
}

double tpsnr(const std::vector<Image>& pred, const std::vector<Image>& gt, MetricSpace space) {
    if (pred.size() != gt.size() || pred.size() < 2)
        throw Error("tPSNR needs two clips of the same length, at least 2 frames");
    double s = 0;
    size_t n = 0;
    Image p0 = to_metric_space(pred[0], space), g0 = to_metric_space(gt[0], space);
    for (size_t t = 1; t < pred.size(); ++t) {
        check_same(pred[t], gt[t], "tPSNR");
        Image p1 = to_metric_space(pred[t], space), g1 = to_metric_space(gt[t], space);
        check_same(p1, p0, "tPSNR");
        for (size_t i = 0; i < p1.size(); ++i) {
            double d =
                (double(p1.pixels[i]) - p0.pixels[i]) - (double(g1.pixels[i]) - g0.pixels[i]);
            s += d * d;
        }
        n += p1.size();
        p0 = std::move(p1);
        g0 = std::move(g1);
    }
    return psnr_from_mse(s / n, peak_of(space));
}

double mean_psnr(const std::vector<Image>& pred, const std::vector<Image>& gt, MetricSpace space) {
    if (pred.size() != gt.size() || pred.empty()) throw Error("PSNR: clips differ in length");
    double s = 0;
    for (size_t t = 0; t < pred.size(); ++t) s += psnr(pred[t], gt[t], space);
    return s / pred.size();
}

double mean_ssim(const std::vector<Image>& pred, const std::vector<Image>& gt, MetricSpace space) {
    if (pred.size() != gt.size() || pred.empty()) throw Error("SSIM: clips differ in length");
    double s = 0;
    for (size_t t = 0; t < pred.size(); ++t) s += ssim(pred[t], gt[t], space);
    return s / pred.size();
}

double masked_psnr(const Image& pred, const Image& gt, const Image& mask, MaskRegion region,
                   MetricSpace space) {
    check_same(pred, gt, "masked PSNR");
    if (mask.width != gt.width || mask.height != gt.height || mask.channels < 1)
        throw Error("masked PSNR: the mask is " + std::to_string(mask.width) + "x" +
                    std::to_string(mask.height) + ", the frames " + std::to_string(gt.width) + "x" +
                    std::to_string(gt.height));
    const Image p = to_metric_space(pred, space), g = to_metric_space(gt, space);
    const int nc = std::min(g.channels, 3);
    double s = 0;
    size_t n = 0;
    for (size_t i = 0; i < static_cast<size_t>(g.width) * g.height; ++i) {
        const bool inside = mask.pixels[i * mask.channels] >= 0.5f;
        if (inside != (region == MaskRegion::Inside)) continue;
        for (int c = 0; c < nc; ++c) {
            const double d = double(p.pixels[i * g.channels + c]) - g.pixels[i * g.channels + c];
            s += d * d;
        }
        n += nc;
    }
    if (n == 0) return std::nan("");
    return psnr_from_mse(s / n, peak_of(space));
}

std::vector<BandError> error_by_band(const std::vector<Image>& pred, const std::vector<Image>& gt,
                                     const std::vector<double>& edges, MetricSpace space) {
    if (pred.size() != gt.size() || pred.empty())
        throw Error("error_by_band: frame counts differ or are zero");
    if (edges.size() < 2 || edges.front() != 0.0 || !std::is_sorted(edges.begin(), edges.end()))
        throw Error("error_by_band: band edges must rise from 0");
    const size_t nb = edges.size() - 1;
    std::vector<BandError> out(nb);
    std::vector<double> cross(nb, 0.0);
    for (size_t i = 0; i < nb; ++i) out[i].lo = edges[i], out[i].hi = edges[i + 1];
    for (size_t t = 0; t < gt.size(); ++t) {
        if (!pred[t].same_shape(gt[t]))
            throw Error("error_by_band: frame " + std::to_string(t) + " differs in size");
        const Image p = to_metric_space(pred[t], space), g = to_metric_space(gt[t], space);
        const int H = g.height, W = g.width;
        std::vector<double> wy(H), wx(W);  // Hann
        for (int y = 0; y < H; ++y) wy[y] = 0.5 - 0.5 * std::cos(2 * M_PI * (y + 0.5) / H);
        for (int x = 0; x < W; ++x) wx[x] = 0.5 - 0.5 * std::cos(2 * M_PI * (x + 0.5) / W);
        for (int c = 0; c < std::min(g.channels, 3); ++c) {
            cv::Mat P(H, W, CV_64F), G(H, W, CV_64F);
            double mp = 0, mg = 0;
            for (int y = 0; y < H; ++y)
                for (int x = 0; x < W; ++x) mp += p.at(x, y, c), mg += g.at(x, y, c);
            mp /= double(H) * W;
            mg /= double(H) * W;
            for (int y = 0; y < H; ++y)
                for (int x = 0; x < W; ++x) {
                    P.at<double>(y, x) = (p.at(x, y, c) - mp) * wy[y] * wx[x];
                    G.at<double>(y, x) = (g.at(x, y, c) - mg) * wy[y] * wx[x];
                }
            cv::Mat FP, FG;
            cv::dft(P, FP, cv::DFT_COMPLEX_OUTPUT);
            cv::dft(G, FG, cv::DFT_COMPLEX_OUTPUT);
            for (int y = 0; y < H; ++y) {
                const double fy = double(y <= H / 2 ? y : y - H) / H;
                for (int x = 0; x < W; ++x) {
                    const double fx = double(x <= W / 2 ? x : x - W) / W;
                    const double f = std::sqrt(fx * fx + fy * fy);
                    const size_t b =
                        std::upper_bound(edges.begin(), edges.end(), f) - edges.begin();
                    if (b == 0 || b > nb) continue;  // beyond the last edge
                    const auto a = FP.at<cv::Vec2d>(y, x), e = FG.at<cv::Vec2d>(y, x);
                    out[b - 1].gt_power += e[0] * e[0] + e[1] * e[1];
                    out[b - 1].err_power +=
                        (a[0] - e[0]) * (a[0] - e[0]) + (a[1] - e[1]) * (a[1] - e[1]);
                    cross[b - 1] += a[0] * e[0] + a[1] * e[1];
                }
            }
        }
    }
    double total = 0;
    for (const auto& b : out) total += b.err_power;
    for (size_t i = 0; i < nb; ++i) {
        out[i].err_share = total > 0 ? out[i].err_power / total : 0.0;
        out[i].gain = out[i].gt_power > 0 ? cross[i] / out[i].gt_power : 0.0;
    }
    return out;
}

}  // namespace refocus
