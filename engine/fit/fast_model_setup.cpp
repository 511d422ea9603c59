// The fast model's set-up from the data: ECC alignment of each frame to the fused atlas, the
// deblurring path (for a layer never seen in focus) and the TV weight maps. Rendering, priors
// and state are fast_model.cpp's.
#include <torch/torch.h>

#include <opencv2/video/tracking.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <mutex>

#include "fit/fast_model.h"
#include "fit/losses.h"
#include "model/atlas_geometry.h"
#include "ops/lens_blur.h"
#include "util/debug.h"
#include "util/error.h"
#include "util/timing.h"

namespace refocus {

namespace {

namespace F = torch::nn::functional;
using FrameFn = std::function<torch::Tensor(int64_t)>;

// The proxy's scale for a frame W px wide: frames at most `width` px wide (0: full size).
int64_t proxy_factor(int64_t W, int64_t width) {
    return width > 0 ? std::max<int64_t>(1, (W + width - 1) / width) : 1;
}

// [C,H,W] → [C,H/k,W/k], k × k block means (the last partial block left out).
torch::Tensor shrink_by(const torch::Tensor& x, int64_t k) {
    if (k == 1) return x;
    const int64_t h = x.size(1) / k, w = x.size(2) / k;
    return torch::avg_pool2d(x.narrow(1, 0, h * k).narrow(2, 0, w * k).unsqueeze(0), k)[0];
}

// A proxy fusion [C,h,w] bilinearly up to the atlas's H × W (align_corners false: proxy texel j
// is the mean of atlas texels kj … kj + k − 1, centred at kj + (k − 1)/2).
torch::Tensor proxy_to_atlas(const torch::Tensor& x, int64_t H, int64_t W) {
    return F::interpolate(x.unsqueeze(0), F::InterpolateFuncOptions()
                                              .size(std::vector<int64_t>{H, W})
                                              .mode(torch::kBilinear)
                                              .align_corners(false))[0];
}

// B⁻¹·M_t·B [T,3,3] float64: frame proxy pixel → atlas proxy texel, B the proxy's scale (proxy
// pixel x_p is the frame's k·x_p + (k − 1)/2, and so for the atlas).
torch::Tensor proxy_mapping(const torch::Tensor& to_atlas, int64_t k) {
    const double c = (k - 1) / 2.0;
    auto B = torch::tensor({double(k), 0.0, c, 0.0, double(k), c, 0.0, 0.0, 1.0}, torch::kFloat64)
                 .view({3, 3});
    return torch::matmul(torch::matmul(torch::inverse(B), to_atlas.to(torch::kFloat64)), B);
}

// Frames fused on a proxy k times smaller than frame and atlas (proxy_mapping), each frame its
// k × k block means, its edges replicated ⌈pad/k⌉ px outward at weight 1e-3 as FastModel::fuse
// does. [C, ⌈Ha/k⌉, ⌈Wa/k⌉].
// With `shrunk`, src and weight give the proxy's frames already.
torch::Tensor fuse_on_proxy(const torch::Tensor& to_atlas, int64_t Ha, int64_t Wa, int64_t k,
                            int64_t pad, const FrameFn& src, const FrameFn& weight,
                            bool shrunk = false) {
    const auto to_proxy = proxy_mapping(to_atlas, k);
    const int64_t ah = (Ha + k - 1) / k, aw = (Wa + k - 1) / k, p = (pad + k - 1) / k;
    auto small = [&](const FrameFn& f, int64_t t) { return shrunk ? f(t) : shrink_by(f(t), k); };
    if (p == 0)
        return fuse_frames(
            to_proxy.to(torch::kFloat32), ah, aw, [&](int64_t t) { return small(src, t); },
            [&](int64_t t) { return small(weight, t); });
    auto edges = [&](const torch::Tensor& x) {
        return F::pad(x.unsqueeze(0), F::PadFuncOptions({p, p, p, p}).mode(torch::kReplicate))[0];
    };
    return fuse_frames(
        torch::matmul(to_proxy, translation(-p, -p).to(torch::kFloat64)).to(torch::kFloat32), ah,
        aw, [&](int64_t t) { return edges(small(src, t)); },
        [&](int64_t t) {
            const auto w = small(weight, t);
            auto inside = F::pad(torch::ones({1, 1, w.size(1), w.size(2)}),
                                 F::PadFuncOptions({p, p, p, p}).value(1e-3))[0];
            return edges(w) * inside;
        });
}

// ECC (Evangelidis & Psarakis 2008) of the reblurred render `moving` onto the frame `tmpl`
// over `mask`, both on the proxy k times smaller than the W × H frame: the correction in frame
// px [3,3] (template pixel x ↦ render w·x), or the identity where ECC does not converge, moves a
// corner max_shift px or more, or, on a camera judged static (hand shake only), where the frame
// does not then match clearly better and well (ECC coefficient > 0.9 and +0.002: noise or
// something in one frame only, a flash or a passer-by, is not hand shake).
torch::Tensor ecc_correction(const cv::Mat& tmpl, const cv::Mat& moving, const cv::Mat& mask,
                             int64_t k, int64_t W, int64_t H, double max_shift, bool static_camera,
                             int round, int64_t t, int motion) {
    // A shift by default: more degrees of freedom let ECC wander on heavily blurred frames.
    cv::Mat warp = cv::Mat::eye(motion == cv::MOTION_HOMOGRAPHY ? 3 : 2, 3, CV_32F);
    bool ok = true;
    try {
        cv::findTransformECC(
            tmpl, moving, warp, motion,
            cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 60, 1e-5), mask, 5);
    } catch (const cv::Exception&) {
        ok = false;  // no convergence: keep the mapping
    }
    // The proxy's map in frame px: frame x = B·x_p with B = [k 0 c; 0 k c; 0 0 1], c = (k − 1)/2,
    // so the frame's map is B·W·B⁻¹ (a shift's c cancels: k times its shift).
    auto wp = torch::eye(3, torch::kFloat64);
    for (int r = 0; r < warp.rows; ++r)
        for (int c = 0; c < 3; ++c) wp[r][c] = double(warp.at<float>(r, c));
    auto B = torch::eye(3, torch::kFloat64);
    B[0][0] = B[1][1] = double(k);
    B[0][2] = B[1][2] = (k - 1) / 2.0;
    auto wf = torch::matmul(torch::matmul(B, wp), torch::inverse(B));
    wf = wf / wf[2][2];
    double worst = 0;
    for (double cy : {0.0, double(H - 1)})
        for (double cx : {0.0, double(W - 1)}) {
            auto q = torch::matmul(wf, torch::tensor({cx, cy, 1.0}, torch::kFloat64));
            worst = std::max(worst, std::hypot(q[0].item<double>() / q[2].item<double>() - cx,
                                               q[1].item<double>() / q[2].item<double>() - cy));
        }
    if (debug_enabled("align"))
        std::fprintf(stderr, "align round %d frame %lld: %s, corner shift %.2f px\n", round,
                     (long long)t, ok ? "ok" : "failed", worst);
    double rho0 = 0, rho1 = 0;
    if (ok && static_camera) {
        cv::Mat warped;
        cv::warpAffine(moving, warped, warp, moving.size(), cv::INTER_LINEAR + cv::WARP_INVERSE_MAP,
                       cv::BORDER_REPLICATE);
        rho0 = cv::computeECC(tmpl, moving, mask);
        rho1 = cv::computeECC(tmpl, warped, mask);
        ok = rho1 > 0.9 && rho1 > rho0 + 0.002;
    }
    if (debug_enabled("align") && static_camera)
        std::fprintf(stderr, "  static frame %lld: ECC coefficient %.4f -> %.4f\n", (long long)t,
                     rho0, rho1);
    return ok && worst < max_shift ? wf : torch::eye(3, torch::kFloat64);
}

}  // namespace

void FastModel::update_tv_weights() {
    // Weighted as the atlases were fused (the sharpest views of each layer), over the atlases'
    // current geometry: a checkpoint may bring its own (adopt_geometry). Each frame's maps are
    // made as the fusion reads them: at 1080p x 240 a clip array of one of them is 2 GB.
    torch::NoGradGuard no_grad;
    const FitData& d = m_data;
    auto sharpness = [&](int64_t t) { return sharpness_weight(d.radius[t]).unsqueeze(0); };
    m_bg.tv_weight = m_fg.tv_weight = torch::Tensor();
    if (int(m_opts.tv_radius_layers) & 1) {
        const auto r = d.layer_radius(false);
        auto views = [&](int64_t t) {
            return m_two_layers ? (1.0 - d.mask[t]).clamp_min(1e-3)
                                : torch::ones({1, d.height, d.width});
        };
        m_bg.tv_weight = tv_weight_map(
            m_bg, [&](int64_t t) { return r[t].unsqueeze(0); },
            [&](int64_t t) { return sharpness(t) * views(t); }, views, m_opts.tv_radius_fade);
    }
    if (m_two_layers && (int(m_opts.tv_radius_layers) & 2)) {
        const auto r = d.layer_radius(true);
        auto views = [&](int64_t t) { return d.mask[t].clamp_min(1e-3); };
        // The subject's layer keeps the weight at any radius (no fade): a subject blurred in
        // every frame (synth pan's, 7 px) gains from it (docs/method.md, Model).
        m_fg.tv_weight = tv_weight_map(
            m_fg, [&](int64_t t) { return r[t].unsqueeze(0); },
            [&](int64_t t) { return sharpness(t) * views(t); }, views, 0.0);
    }
}

torch::Tensor FastModel::tv_weight_map(const Atlas& a, const FrameFn& radius, const FrameFn& weight,
                                       const FrameFn& views, double fade) const {
    // The radii each texel was seen at, fused into the atlas: toward its sharpest views (as the
    // texels are) and over all its views alike (their mean and spread); see tv_radius_factor.
    // The mean and the mean square share their weights: one fusion of two channels.
    // Frames wider than the alignment's proxy are fused on it: the radius maps are the
    // preparation's proxy scaled up (or a given map), and the factor is a smooth weight.
    const double cap = m_opts.tv_radius_cap;
    if (!(cap > 1)) return torch::Tensor();
    const int64_t k = proxy_factor(m_data.width, m_opts.align_width);
    auto moment = [&](int64_t t) {
        const auto r = radius(t);
        return torch::cat({r, r * r}, 0);
    };
    torch::Tensor sharp, moments;  // [1,·,·] ~ the smallest radius seen; [2,·,·] each view alike
    if (k == 1) {
        sharp = fuse(a, weight, radius);
        moments = fuse(a, views, moment);
    } else {
        sharp = fuse_on_proxy(a.to_atlas, a.height, a.width, k, m_opts.pad, radius, weight);
        moments = fuse_on_proxy(a.to_atlas, a.height, a.width, k, m_opts.pad, moment, views);
    }
    auto f = tv_radius_factor(sharp, moments.narrow(0, 0, 1), moments.narrow(0, 1, 1),
                              m_opts.tv_radius_gain, cap, m_opts.tv_radius_spread, fade);
    if (k > 1) f = proxy_to_atlas(f, a.height, a.width);
    return f.unsqueeze(0);
}

FastModel::FrameFn FastModel::shrunk_once(FrameFn full) const {
    const int64_t k = proxy_factor(m_data.width, m_opts.align_width);
    if (k == 1) return {};
    // A clip array (mapped through work/ where the clip's frames are), made at the first read.
    // Fusions read frames on two threads (fuse_frames), each frame on one: the array is made
    // under a lock, a frame's slot by the thread that reads it.
    struct Memo {
        std::mutex lock;
        torch::Tensor frames;
        std::vector<char> made;
    };
    auto memo = std::make_shared<Memo>();
    memo->made.assign(m_data.frames, 0);
    const FitData* d = &m_data;
    return [full = std::move(full), k, memo, d](int64_t t) {
        if (!memo->made[t]) {
            const auto x = shrink_by(full(t), k);
            torch::Tensor frames;
            {
                std::lock_guard<std::mutex> hold(memo->lock);
                if (!memo->frames.defined())
                    memo->frames =
                        d->clip_array({int64_t(d->frames), x.size(0), x.size(1), x.size(2)});
                frames = memo->frames;
            }
            frames[t].copy_(x);
            memo->made[t] = 1;
        }
        return memo->frames[t];
    };
}

torch::Tensor FastModel::fuse_regions(const Atlas& a, const FrameFn& weight, const FrameFn& region,
                                      const FrameFn& weight_p) const {
    const int64_t k = proxy_factor(m_data.width, m_opts.align_width);
    auto src = [&](int64_t t) { return m_data.input[t]; };
    if (k == 1) return fuse(a, weight, src);
    // A frame's box: its region grown by the widest blur (light the layer spreads past its
    // mask) and a little, mapped into the atlas, plus the bicubic taps.
    const double grow = double(m_opts.pad) + 8.0;
    const int64_t T = m_data.frames;
    std::vector<TexelBox> boxes(T);
    int64_t texels = 0;
    for (int64_t t = 0; t < T; ++t) {
        const auto nz = torch::nonzero(region(t)[0] > 0.02);
        if (nz.size(0) == 0) continue;
        const auto lo = std::get<0>(nz.min(0)), hi = std::get<0>(nz.max(0));
        boxes[t] = mapped_box(a.to_atlas, t, lo[1].item<double>() - grow,
                              lo[0].item<double>() - grow, hi[1].item<double>() + grow,
                              hi[0].item<double>() + grow, 3.0, a.height, a.width);
        texels += boxes[t].w * boxes[t].h;
    }
    // Regions that fill most of the atlas anyway: the whole frames, as everywhere else.
    if (texels > T * a.height * a.width / 2) return fuse(a, weight, src);
    const auto fallback = proxy_to_atlas(
        m_input_p && weight_p
            ? fuse_on_proxy(a.to_atlas, a.height, a.width, k, m_opts.pad, m_input_p, weight_p, true)
            : fuse_on_proxy(a.to_atlas, a.height, a.width, k, m_opts.pad, src, weight),
        a.height, a.width);
    return fuse(
        a, weight, src, false, [&](int64_t t) { return boxes[t]; }, fallback);
}

void FastModel::refine_alignment(Atlas& a, const FrameFn& weight, const FrameFn& weight_p,
                                 const FrameFn& region, double max_shift, bool static_camera,
                                 const std::vector<int64_t>* only, int rounds) {
    const int64_t T = m_data.frames, H = m_data.height, W = m_data.width;
    // ECC runs on a proxy at most align_width px wide: its window and iterations are tuned in
    // px, and the reblur's cost would grow with the square of the scale twice over. Proxy pixel
    // x_p is the frame's k·x_p + (k − 1)/2 (the mean of a k × k block).
    const int64_t k = proxy_factor(W, m_opts.align_width);
    const int64_t h = H / k, w = W / k;
    torch::Tensor pixels = m_pixels;  // the proxy's pixel centres in frame px
    if (k > 1) {
        auto ys = torch::arange(h, torch::kFloat32) * double(k) + (k - 1) / 2.0,
             xs = torch::arange(w, torch::kFloat32) * double(k) + (k - 1) / 2.0;
        auto g = torch::meshgrid({ys, xs}, "ij");
        pixels = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({h * w})}, 1);
    }
    auto shrink = [&](const torch::Tensor& x) { return shrink_by(x, k); };  // [C,h,w]
    const FrameFn input_p =
        m_input_p ? m_input_p : [&](int64_t t) { return shrink(m_data.input[t]); };
    const FrameFn wp = weight_p ? weight_p : [&](int64_t t) { return shrink(weight(t)); };
    // On a proxy the atlas is fused from the proxy frames too (fuse_on_proxy): the render reads
    // nothing finer, and the fusion costs k² less; 1280×720×60: the background's corners land
    // within 0.03 px (median) of the full-size fusion's. The subject's atlas spans its track,
    // larger than the frame on a long clip of walkers (1920×1080×240: 2.4 times the frame).
    const bool proxy_atlas = k > 1;
    torch::Tensor proxy_px, to_proxy;  // proxy pixel grid [h·w,3]; B⁻¹·M_t·B [T,3,3]
    const int64_t ah = (a.height + k - 1) / k, aw = (a.width + k - 1) / k;
    if (proxy_atlas) {
        auto g = torch::meshgrid(
            {torch::arange(h, torch::kFloat32), torch::arange(w, torch::kFloat32)}, "ij");
        proxy_px = torch::stack({g[1].flatten(), g[0].flatten(), torch::ones({h * w})}, 1);
    }
    auto grey = [&](const torch::Tensor& rgb) {  // [3,h',w'] linear → sRGB luma, CV_32F
        auto l = srgb_encode(rgb);
        l = (0.299 * l[0] + 0.587 * l[1] + 0.114 * l[2]).contiguous();
        return cv::Mat(int(l.size(0)), int(l.size(1)), CV_32F, l.data_ptr<float>()).clone();
    };
    const int n_rounds = rounds < 0 ? m_opts.align_rounds : rounds;
    const int motion = m_opts.align_motion == "homography" ? cv::MOTION_HOMOGRAPHY
                       : m_opts.align_motion == "affine"   ? cv::MOTION_AFFINE
                                                           : cv::MOTION_TRANSLATION;
    for (int round = 0; round < n_rounds; ++round) {
        torch::Tensor fused;
        {
            ScopedTiming timing("align: fuse");
            if (!proxy_atlas) {
                fused = fuse(a, weight, [&](int64_t t) { return m_data.input[t]; }).unsqueeze(0);
            } else {
                to_proxy = proxy_mapping(a.to_atlas, k).to(torch::kFloat32);
                fused = fuse_on_proxy(a.to_atlas, a.height, a.width, k, 0, input_p, wp, true)
                            .unsqueeze(0);
            }
        }
        std::vector<torch::Tensor> mats;
        for (int64_t t = 0; t < T; ++t) {
            auto m = a.to_atlas[t].to(torch::kFloat64);
            if (only && !std::binary_search(only->begin(), only->end(), t)) {
                mats.push_back(m);
                continue;
            }
            auto rmask = (shrink(region(t))[0] > 0.5).to(torch::kUInt8).mul(255).contiguous();
            const cv::Mat full_mask(int(h), int(w), CV_8U, rmask.data_ptr<uint8_t>());
            if (cv::countNonZero(full_mask) < 64) {
                mats.push_back(m);
                continue;
            }
            // Only the region's box is rendered and matched, grown by what reaches into it (the
            // blur's support, the largest shift ECC may take, its 5 px smoothing): a subject's
            // box is a fraction of the frame; a wall's is the whole frame, as before.
            const auto radius = shrink(m_data.radius[t].unsqueeze(0))[0].div(double(k));
            const int grow =
                int(std::ceil(lens_blur_support(radius.max().item<double>(), m_data.blur) +
                              max_shift / double(k))) +
                8;
            const cv::Rect box = (cv::boundingRect(full_mask) + cv::Size(2 * grow, 2 * grow) -
                                  cv::Point(grow, grow)) &
                                 cv::Rect(0, 0, int(w), int(h));
            auto crop = [&](const torch::Tensor& x) {  // [..., h, w] → the box
                return x.narrow(-2, box.y, box.height).narrow(-1, box.x, box.width);
            };
            const cv::Mat mask = full_mask(box).clone();
            cv::Mat tmpl, moving;
            {
                ScopedTiming timing("align: render and reblur");
                torch::Tensor grid;
                if (!proxy_atlas) {
                    auto q = crop(pixels.t().reshape({3, h, w})).reshape({3, -1});
                    auto p = torch::matmul(a.to_atlas[t], q);
                    grid = to_grid(a, (p.narrow(0, 0, 2) / p.narrow(0, 2, 1))
                                          .t()
                                          .view({1, box.height, box.width, 2}));
                } else {
                    auto q = crop(proxy_px.t().reshape({3, h, w})).reshape({3, -1});
                    auto p = torch::matmul(to_proxy[t], q);
                    auto px = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1))
                                  .t()
                                  .view({1, box.height, box.width, 2});
                    grid = (px + 0.5) * torch::tensor({2.0f / aw, 2.0f / ah}) - 1.0;
                }
                auto render = sample_bicubic(fused, grid)[0];
                auto blurred =
                    lens_blur(render.contiguous(), crop(radius).contiguous(), m_data.blur);
                tmpl = grey(crop(input_p(t))), moving = grey(blurred);
            }
            ScopedTiming timing("align: ECC");
            mats.push_back(torch::matmul(
                m, ecc_correction(tmpl, moving, mask, k, W, H, max_shift, static_camera, round, t,
                                  static_camera ? cv::MOTION_TRANSLATION : motion)));
        }
        a.to_atlas = torch::stack(mats).to(torch::kFloat32);
    }
}

std::string FastModel::make_deblur_path(Atlas& a, const torch::Tensor& radius,
                                        const torch::Tensor& weight, const torch::Tensor& views,
                                        const char* name) {
    // Only for a layer that no frame saw in focus: the median, over the texels that the layer
    // covers in most of their views, of the radius each was seen at sharpest (fused as the
    // texels are). Where focus reached a layer its sharp views carry the detail already, and
    // the path would only fit the radius's errors (docs/method.md, Deblurring path).
    torch::NoGradGuard no_grad;
    const auto cover = fuse(a, torch::ones_like(views), views) > 0.5;
    if (!cover.any().item<bool>()) return {};
    const double r =
        fuse(a, weight, radius.unsqueeze(1)).masked_select(cover).median().item<double>();
    char line[200];
    if (!(r >= m_opts.deblur_min_radius)) {
        std::snprintf(line, sizeof line,
                      "fit (fast): %s atlas: no deblurring path (seen in focus: median sharpest "
                      "radius %.1f px < %.1f)",
                      name, r, m_opts.deblur_min_radius);
        return line;
    }
    // Q(f) = sqrt(max(0, 1/(env(f)^2 + eps) - 1)) on the frame's grid, where env is the envelope
    // of the pillbox's transfer function 2 J1(x)/x at x = 2 pi r |f|: 1 up to its main lobe, then
    // ~1.6 x^-1.5 (|J1(x)| <= sqrt(2/(pi x))). Zero at low frequencies: the texels carry those.
    const int64_t N = 64, k = m_opts.deblur_kernel | 1;
    auto f = torch::fft::fftfreq(N, torch::TensorOptions().dtype(torch::kFloat64));
    auto x = 2 * M_PI * r * (f.view({N, 1}).pow(2) + f.view({1, N}).pow(2)).sqrt();
    auto env = torch::clamp(1.6 * x.clamp_min(1e-6).pow(-1.5), 0.0, 1.0);
    auto Q = (1.0 / (env * env + m_opts.deblur_eps) - 1.0).clamp_min(0.0).sqrt();
    auto ker = torch::real(torch::fft::ifft2(Q.to(torch::kComplexDouble)));
    ker = torch::roll(ker, {k / 2, k / 2}, {0, 1}).narrow(0, 0, k).narrow(1, 0, k);
    ker = (ker - ker.mean()).to(torch::kFloat32);  // the cut keeps no DC
    a.deblur_kernel = ker.view({1, 1, k, k}).expand({3, 1, k, k}).contiguous();
    const int64_t s = std::max<int64_t>(1, std::lround(a.scale));
    a.deblur =
        torch::zeros({1, 3, (a.height + s - 1) / s, (a.width + s - 1) / s}).set_requires_grad(true);
    std::snprintf(line, sizeof line,
                  "fit (fast): %s atlas: deblurring path (never seen in focus: median sharpest "
                  "radius %.1f px; gain up to %.0fx)",
                  name, r, Q.max().item<double>());
    return line;
}

}  // namespace refocus
