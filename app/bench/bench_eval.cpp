// Scoring a fit against ground truth, shared by bench fit and bench corpus (bench_eval.h).
#include "bench_eval.h"

#include <algorithm>
#include <cmath>

#include "fit/settings.h"
#include "project/project.h"

#include "io/tensor_image.h"
#include "metrics/metrics.h"

namespace refocus {

EvalRow evaluate(FitEngine& engine, const std::vector<Image>& gt, const std::vector<Image>& input,
                 EvalFrames* keep) {
    std::vector<Image> sharp, reblur, g, in, model;
    std::vector<int> index;
    for (int t = 0; t < static_cast<int>(gt.size()); ++t) {
        if (!engine.frame_done(t)) continue;
        Layers L = engine.render_frame(t);
        torch::NoGradGuard ng;
        reblur.push_back(tensor_to_image(engine.reblur(L, {t})[0].clamp_min(0)));
        if (keep) model.push_back(tensor_to_image(L.sharp[0].clamp_min(0)));
        engine.apply_fallback(L, t);
        sharp.push_back(tensor_to_image(L.sharp[0].clamp_min(0)));
        g.push_back(gt[t]);
        in.push_back(input[t]);
        index.push_back(t);
    }
    EvalRow r;
    FitSnapshot s = engine.snapshot();
    r.minutes = s.elapsed_s / 60.0;
    r.step = s.step;
    r.frames_done = static_cast<int>(sharp.size());
    if (sharp.empty()) return r;
    r.psnr = mean_psnr(sharp, g);
    r.ssim = mean_ssim(sharp, g);
    r.reblur_psnr = mean_psnr(reblur, in);
    r.in_psnr = mean_psnr(in, g);
    r.in_ssim = mean_ssim(in, g);
    // Consecutive frames only (all of them unless perframe stopped early: it goes in order).
    int run = 0;
    while (run < static_cast<int>(gt.size()) && engine.frame_done(run)) ++run;
    if (run > 1) {
        std::vector<Image> a(sharp.begin(), sharp.begin() + run), b(g.begin(), g.begin() + run),
            c(in.begin(), in.begin() + run);
        r.tpsnr = tpsnr(a, b);
        r.in_tpsnr = tpsnr(c, b);
    }
    if (keep)
        *keep = EvalFrames{std::move(sharp), std::move(g), std::move(in), std::move(model),
                           std::move(index)};
    return r;
}

namespace {
// A box mean of a one-channel map over (2r+1)^2 px, edges replicated.
std::vector<double> box_mean(const std::vector<double>& m, int w, int h, int r) {
    std::vector<double> tmp(m.size()), out(m.size());
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double s = 0;
            for (int d = -r; d <= r; ++d) s += m[size_t(y) * w + std::clamp(x + d, 0, w - 1)];
            tmp[size_t(y) * w + x] = s / (2 * r + 1);
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double s = 0;
            for (int d = -r; d <= r; ++d) s += tmp[size_t(std::clamp(y + d, 0, h - 1)) * w + x];
            out[size_t(y) * w + x] = s / (2 * r + 1);
        }
    return out;
}
}  // namespace

double oracle_blend_psnr(const Image& model, const Image& input, const Image& gt) {
    const Image m = to_metric_space(model), i = to_metric_space(input), g = to_metric_space(gt);
    const int w = g.width, h = g.height, C = g.channels;
    std::vector<double> em(size_t(w) * h), ei(size_t(w) * h);
    for (size_t p = 0; p < em.size(); ++p)
        for (int c = 0; c < std::min(C, 3); ++c) {
            const double a = m.pixels[p * C + c] - g.pixels[p * C + c];
            const double b = i.pixels[p * C + c] - g.pixels[p * C + c];
            em[p] += a * a, ei[p] += b * b;
        }
    em = box_mean(em, w, h, 1);
    ei = box_mean(ei, w, h, 1);
    std::vector<double> pick(em.size());
    for (size_t p = 0; p < em.size(); ++p) pick[p] = em[p] < ei[p] ? 1.0 : 0.0;
    pick = box_mean(pick, w, h, 1);
    Image blend = g;
    for (size_t p = 0; p < pick.size(); ++p)
        for (int c = 0; c < C; ++c)
            blend.pixels[p * C + c] = float(
                std::round(pick[p] * m.pixels[p * C + c] + (1 - pick[p]) * i.pixels[p * C + c]));
    return std::min(100.0, psnr_from_mse(mse(blend, g), 255.0));
}

FitSettings bench_fit_settings(const Args& a, const std::string& preset, double minutes) {
    FitSettings s;
    Settings settings;
    for (const auto& assignment : a.get_all("set")) settings.set_assignment(assignment);
    use_settings(s, settings);
    s.fit.preset = preset;
    s.fit.minutes = minutes;
    s.fit.iters = a.get_int("iters", 0);
    s.fit.seed = a.has("seed") ? static_cast<uint64_t>(checked_fit_flag("seed", a.get("seed"))) : 1;
    if (a.has("batch"))  // frames per step; left out: the model's choice
        s.fit.batch = checked_batch_arg(checked_fit_flag("batch", a.get("batch")));
    return s;
}

}  // namespace refocus
