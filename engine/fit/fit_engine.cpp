#include "fit/fit_engine.h"

#include <torch/optim.h>
#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "fit/confidence.h"
#include "fit/lazy_adam.h"
#include "fit/losses.h"
#include "radius/stack_coc.h"
#include "io/tensor_image.h"
#include "io/image_file.h"
#include "ops/morphology.h"
#include "util/debug.h"
#include "model/clip_cache.h"
#include "util/timing.h"
#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

using Clock = std::chrono::steady_clock;

namespace {
// What a diverged fit leaves and what to do.
const char* const kDivergedAdvice =
    "; the fit stopped and the last checkpoint (fit/checkpoint.json) is kept: check the input for "
    "extreme values, or fit again without --resume";
}  // namespace

int checked_batch_arg(int64_t n) {
    if (n < 1)
        throw Error("fit: --batch must be at least 1 frame per step (got " + std::to_string(n) +
                    ")");
    return static_cast<int>(n);
}

FitEngine::FitEngine(std::shared_ptr<FitData> data, const FitOptions& opts)
    : m_data(std::move(data)), m_opts(opts), m_rng(opts.seed) {
    apply_settings(m_opts.settings, m_opts);
    find_preset(m_opts.preset);  // an unknown preset is refused before the data are touched
    if (!m_data || m_data->frames <= 0) throw Error("fit: the clip has no frames");
    if (m_opts.minutes <= 0 && m_opts.iters <= 0)
        throw Error("fit: give a budget (--minutes M or --iters N)");
    if (m_opts.batch < 0) checked_batch_arg(m_opts.batch);  // 0: the model's choice
    if (m_opts.crop_px != 0 && m_opts.crop_px < 32)
        throw Error("fit: fit.crop_px must be 0 (whole frames) or at least 32 px (got " +
                    std::to_string(m_opts.crop_px) + ")");
    StageClock clock;  // --debug timing
    clock.next("set-up: checks");
    {
        torch::NoGradGuard g;
        // Frame by frame: a long clip's arrays are file mappings (util/mapped.h), and a check
        // over the whole clip at once would hold a clip-sized temporary.
        check_finite(*m_data);
        // The running residual is made at the first step (finish_restore): an engine opened from
        // its checkpoint reads the checkpoint's instead.
    }
    clock.end();
    build_model();
}

void FitEngine::build_model() {
    const bool atlas = has_atlas();  // a model without atlases blurs each frame by its own map
    {
        StageClock clock;
        clock.next("set-up: each layer's radius", "each layer's radius");
        if (m_opts.layer_radius && atlas)
            split_layer_radius();
        else
            m_data->radius_fg = m_data->radius_bg = torch::Tensor();
    }
    debug_memory("engine: radius split by layer");
    m_model = make_model(m_opts.preset, *m_data, m_opts.seed, m_opts.settings);
    debug_memory("engine: model made");
    if (atlas && debug_enabled("init-atlas")) {
        // Start from given atlases (<dir>/atlas_bg.exr, and atlas_fg.exr where the file is
        // there), e.g. the ground truth splatted through a fitted project's UV, to see where
        // the objective's own optimum lies.
        const std::string dir = debug_value("init-atlas");
        m_model->set_atlas_bg(image_to_tensor(read_image_file(dir + "/atlas_bg.exr").image));
        if (std::filesystem::exists(dir + "/atlas_fg.exr"))
            m_model->set_atlas_fg(image_to_tensor(read_image_file(dir + "/atlas_fg.exr").image));
    }
    m_batch = m_opts.batch > 0 ? m_opts.batch : m_model->preferred_batch();
    if (m_opts.batch == 0 && m_batch != 2)
        m_model->notes.push_back("fit: " + std::to_string(m_batch) + " frames a step (" +
                                 m_model->preferred_batch_reason() + ")");
    m_pad = m_model->max_pad();
    // A crop is blurred with the margin the model renders around it (FitModel::render_window),
    // as a whole frame is: a model that renders none beyond the frame (paper) takes whole
    // frames, unless nothing is blurred (docs/method.md, Crops).
    const bool smaller =
        m_opts.crop_px > 0 && (m_data->width > m_opts.crop_px || m_data->height > m_opts.crop_px);
    const bool margin =
        m_pad > 0 || lens_blur_support(m_data->radius.max().item<double>(), m_data->blur) == 0;
    m_crops = smaller && margin && !m_model->steps_itself();
    if (m_crops)
        m_model->notes.push_back("fit: a step takes crops of about " +
                                 std::to_string(m_opts.crop_px) +
                                 " px a side of each frame (fit.crop_px; 0: whole frames)");
    else if (smaller && !m_model->steps_itself())
        m_model->notes.push_back("fit: whole frames a step: the " + m_opts.preset +
                                 " model renders no margin beyond the frame, which crops need");
    make_optimizer();
}

void FitEngine::split_layer_radius() {
    FitData& d = *m_data;
    // A long clip's last command may have kept the split (model/clip_cache.h): it follows from
    // the clip's kept arrays, and from the cleaned masks (a legacy checkpoint's are the stored).
    const bool keep =
        !d.cache_key.empty() && d.has_subject && d.mask.defined() && !d.legacy_track_gaps;
    const std::string key = d.cache_key + "/layers-v1";
    if (keep) {
        auto fg = kept_clip_array(d, "radius_fg", d.radius.sizes(), key),
             bg = kept_clip_array(d, "radius_bg", d.radius.sizes(), key);
        if (fg.defined() && bg.defined()) {
            d.radius_fg = fg, d.radius_bg = bg;
            return;
        }
    }
    split_radius_by_layer(d);
    if (keep) try {
            keep_clip_array(d, "radius_fg", d.radius_fg, key);
            keep_clip_array(d, "radius_bg", d.radius_bg, key);
        } catch (const std::exception&) {
            // a full disk: the next command splits them again
        }
}

FitEngine::~FitEngine() = default;

const std::vector<std::string>& FitEngine::model_notes() const {
    return m_model->notes;
}

void FitEngine::make_optimizer() {
    std::vector<torch::optim::OptimizerParamGroup> groups;
    m_base_lr.clear();
    m_optim.reset();
    if (m_model->steps_itself()) return;
    for (auto& g : m_model->param_groups()) {
        groups.emplace_back(g.params, std::make_unique<torch::optim::AdamOptions>(g.lr));
        m_base_lr.push_back(g.lr);
    }
    // Crops train part of each atlas a step: the others must not drift (lazy_adam.h).
    if (m_crops)
        m_optim = std::make_unique<LazyAdam>(groups, torch::optim::AdamOptions(1e-3));
    else
        m_optim = std::make_unique<torch::optim::Adam>(groups, torch::optim::AdamOptions(1e-3));
}

double FitEngine::budget_fraction() const {
    double f = 0.0;
    if (m_opts.iters > 0) f = std::max(f, double(m_step) / m_opts.iters);
    if (m_opts.minutes > 0) f = std::max(f, m_elapsed / (60.0 * m_opts.minutes));
    return std::min(f, 1.0);
}

bool FitEngine::done() const {
    if (m_stop) return true;
    // perframe: all frames, or the time budget (checked between frames, so a frame started
    // before the budget ran out finishes); --iters counts frames there.
    if (m_model->steps_itself()) return m_step >= m_model->step_count() || budget_fraction() >= 1.0;
    return budget_fraction() >= 1.0;
}

std::vector<int64_t> FitEngine::next_batch() {
    // Epochs over a shuffled permutation: every frame is seen equally often.
    std::vector<int64_t> b;
    const int n = std::min<int>(m_batch, m_data->frames);
    while (static_cast<int>(b.size()) < n) {
        if (m_perm_pos >= m_perm.size()) {
            m_perm.resize(m_data->frames);
            for (int64_t i = 0; i < m_data->frames; ++i) m_perm[i] = i;
            std::shuffle(m_perm.begin(), m_perm.end(), m_rng);
            m_perm_pos = 0;
        }
        b.push_back(m_perm[m_perm_pos++]);
    }
    return b;
}

namespace {

// Frame t of [T,H,W] maps over rows y0..y0+h and columns x0..x0+w of the frame, its border
// repeated beyond it: what a replicate-padded map holds there, without a padded copy of the
// clip's maps (util/mapped.h: those stay in their file).
torch::Tensor map_window(const torch::Tensor& maps, int64_t t, int64_t y0, int64_t x0, int64_t h,
                         int64_t w) {
    const int64_t H = maps.size(1), W = maps.size(2);
    const auto frame = maps[t];
    if (y0 >= 0 && x0 >= 0 && y0 + h <= H && x0 + w <= W)
        return frame.narrow(0, y0, h).narrow(1, x0, w);
    auto ys = torch::arange(y0, y0 + h, torch::kLong).clamp(0, H - 1);
    auto xs = torch::arange(x0, x0 + w, torch::kLong).clamp(0, W - 1);
    return frame.index_select(0, ys).index_select(1, xs);
}

}  // namespace

torch::Tensor FitEngine::reblur(const Layers& L, const std::vector<int64_t>& frames) const {
    // Layers rendered with a margin (render_padded) are blurred with the radius maps padded
    // alike and cropped back to the frame.
    const int64_t pad = (L.sharp.size(3) - m_data->width) / 2;
    if (pad != 0 && pad != m_pad) throw Error("reblur: layers padded by an unexpected margin");
    std::vector<torch::Tensor> out;
    const int64_t H = m_data->height, W = m_data->width;
    for (size_t b = 0; b < frames.size(); ++b) {
        const int64_t t = frames[b];
        auto map = [&](const torch::Tensor& maps) {
            return map_window(maps, t, -pad, -pad, H + 2 * pad, W + 2 * pad);
        };
        out.push_back(reblur_frame(L, b, t, map(m_data->radius), map(m_data->layer_radius(true)),
                                   map(m_data->layer_radius(false))));
    }
    auto rb = torch::stack(out);
    return pad ? rb.narrow(2, pad, m_data->height).narrow(3, pad, m_data->width) : rb;
}

torch::Tensor FitEngine::reblur_frame(const Layers& L, size_t b, int64_t t, const torch::Tensor& r,
                                      const torch::Tensor& rf, const torch::Tensor& rb) const {
    if (!L.fg.defined()) return lens_blur(L.sharp[b], r, m_data->blur);  // paper eq. 3
    // Layered reblur L(α·F) + (1 − L(α))·L(B): α·F and α scatter with the subject's radius,
    // B with the wall's (the same map for both unless split_radius_by_layer gave two, then
    // two passes).
    auto a = L.alpha[b];
    if (m_data->radius_fg.defined()) {
        auto blf = lens_blur(torch::cat({a * L.fg[b], a}, 0), rf, m_data->blur);
        auto blb = lens_blur(L.bg[b], rb, m_data->blur);
        return blf.narrow(0, 0, 3) + (1.0 - blf.narrow(0, 3, 1)) * blb;
    }
    auto bl = lens_blur(torch::cat({a * L.fg[b], a, L.bg[b]}, 0), rf,
                        m_data->blur);  // one 7-channel pass
    return bl.narrow(0, 0, 3) + (1.0 - bl.narrow(0, 3, 1)) * bl.narrow(0, 4, 3);
}

Crops FitEngine::step_crops(const std::vector<int64_t>& frames) const {
    if (!m_crops) {
        Crops whole;
        whole.w = m_data->width;
        whole.h = m_data->height;
        whole.x = whole.y = std::vector<int64_t>(frames.size(), 0);
        return whole;
    }
    return draw_crops(m_data->width, m_data->height, m_opts.crop_px, m_opts.seed, m_step,
                      frames.size());
}

torch::Tensor FitEngine::reblur_crops(const Layers& L, const std::vector<int64_t>& frames,
                                      const Crops& c, const Windows& win) const {
    std::vector<torch::Tensor> out;
    for (size_t b = 0; b < frames.size(); ++b) {
        const int64_t t = frames[b];
        auto window = [&](const torch::Tensor& maps) {
            return map_window(maps, t, win.y0[b], win.x0[b], win.h, win.w);
        };
        auto blurred =
            reblur_frame(L, b, t, window(m_data->radius), window(m_data->layer_radius(true)),
                         window(m_data->layer_radius(false)));
        out.push_back(
            blurred.narrow(1, c.y[b] - win.y0[b], c.h).narrow(2, c.x[b] - win.x0[b], c.w));
    }
    return torch::stack(out);
}

namespace {

// The layers over the windows, their gradient kept inside the crops only (the values
// everywhere): the margin around a crop holds light the blur spreads into it, and a texel seen
// only there, through the blur alone, is barely determined by the crop; Adam would move it by
// its full step all the same (docs/method.md, Crops).
Layers train_crops_only(Layers L, const Crops& c, const Windows& win) {
    auto mask = torch::zeros({int64_t(c.x.size()), 1, win.h, win.w});
    for (size_t b = 0; b < c.x.size(); ++b)
        mask[int64_t(b)]
            .narrow(1, c.y[b] - win.y0[b], c.h)
            .narrow(2, c.x[b] - win.x0[b], c.w)
            .fill_(1.0f);
    auto keep = [&](torch::Tensor& x) {
        if (x.defined()) x = x.detach() + (x - x.detach()) * mask;
    };
    keep(L.sharp);
    keep(L.bg);
    keep(L.fg);
    keep(L.alpha);
    return L;
}

// The layers over the windows cut to the crops (x0, y0: the crops' corners).
Layers cut_to_crops(const Layers& L, const Crops& c, const Windows& win) {
    auto cut = [&](const torch::Tensor& x, int64_t dy) {  // dy: the row dimension of x[b]
        if (!x.defined()) return x;
        std::vector<torch::Tensor> per;
        for (size_t b = 0; b < c.x.size(); ++b)
            per.push_back(x[int64_t(b)]
                              .narrow(dy, c.y[b] - win.y0[b], c.h)
                              .narrow(dy + 1, c.x[b] - win.x0[b], c.w));
        return torch::stack(per);
    };
    Layers out;
    out.sharp = cut(L.sharp, 1);
    out.bg = cut(L.bg, 1);
    out.fg = cut(L.fg, 1);
    out.alpha = cut(L.alpha, 1);
    out.uv_bg = cut(L.uv_bg, 0);
    out.uv_fg = cut(L.uv_fg, 0);
    out.x0 = c.x;
    out.y0 = c.y;
    return out;
}

// The median of a frame's running residual ([1,H,W]) over the pixels crops have reached (−1:
// not yet), on a lattice of at most ~65k of them: the frame's typical residual at a cost that
// does not grow with the frame.
double seen_median(const torch::Tensor& r) {
    const int64_t H = r.size(1), W = r.size(2);
    const int64_t s = std::max<int64_t>(1, int64_t(std::sqrt(double(H * W) / 65536.0)));
    auto v = r.slice(1, 0, H, s).slice(2, 0, W, s).flatten();
    auto seen = v.masked_select(v >= 0);
    return seen.numel() > 0 ? seen.median().item<double>() : 0.0;
}

}  // namespace

torch::Tensor FitEngine::robust_target(const torch::Tensor& rb, const torch::Tensor& target,
                                       const std::vector<int64_t>& frames, const Crops& c) {
    const bool robust = m_opts.robust_c > 0;
    if (!robust && !(m_opts.fallback_k > 0)) return target;  // nothing needs the residual
    torch::NoGradGuard no_grad;
    // Residual of this step, smoothed over 5x5 px (a single pixel's error is noise), folded into
    // the frame's running residual (the atlases move slowly; one step's error alone flickers).
    auto e = (rb.detach() - target).abs().mean(1, true);
    e = box_filter(e, 2);
    std::vector<torch::Tensor> w;
    for (size_t b = 0; b < frames.size(); ++b) {
        // A crop updates its window of the frame's residual (a view into m_resid).
        auto r = c.whole ? m_resid[frames[b]]
                         : m_resid[frames[b]].narrow(1, c.y[b], c.h).narrow(2, c.x[b], c.w);
        auto fresh = e[b];
        r.copy_(torch::where(r < 0, fresh, 0.7 * r + 0.3 * fresh));
        if (!robust) continue;
        const double scale =
            std::max(c.whole ? r.median().item<double>() : seen_median(m_resid[frames[b]]), 1e-4);
        w.push_back(1.0 / (1.0 + (r / (m_opts.robust_c * scale)).pow(2)));
    }
    if (!robust || m_step < m_opts.robust_warmup) return target;
    // Where the weight is low the target becomes the current reblur: no gradient from there,
    // for the L1 and the MS-SSIM terms alike.
    auto wt = torch::stack(w);
    return wt * target + (1.0 - wt) * rb.detach();
}

FitEngine::StepRender FitEngine::render_step(const std::vector<int64_t>& frames,
                                             const Crops& crops) {
    StepRender r;
    r.scored = crops;
    if (crops.whole) {  // the reference path
        r.trained = m_model->render_padded(frames, m_pad);
        r.reblur = srgb_encode(reblur(r.trained, frames));
        r.target = srgb_encode(m_data->input.index_select(0, torch::tensor(frames, torch::kLong)));
        return r;
    }
    // The crop is what this step trains; the loss scores it and the pixels its blur reaches
    // (the crop's gradient is then the whole frame's), over a window with the blur's margin
    // around those (docs/method.md, Crops).
    r.scored = grow_crops(crops, m_data->width, m_data->height, m_pad);
    const Windows win = crop_windows(r.scored, m_data->width, m_data->height, m_pad, m_pad);
    std::vector<torch::Tensor> t;
    for (size_t b = 0; b < frames.size(); ++b)
        t.push_back(m_data->input[frames[b]]
                        .narrow(1, r.scored.y[b], r.scored.h)
                        .narrow(2, r.scored.x[b], r.scored.w));
    const Layers L =
        train_crops_only(m_model->render_window(frames, win.x0, win.y0, win.h, win.w), crops, win);
    r.reblur = srgb_encode(reblur_crops(L, frames, r.scored, win));
    r.target = srgb_encode(torch::stack(t));
    r.trained = cut_to_crops(L, crops, win);  // what the priors see: the crops
    return r;
}

void FitEngine::finish_restore() {
    torch::NoGradGuard g;
    if (!m_pending_optim.empty()) {
        const fs::path file = m_pending_optim;
        m_pending_optim.clear();
        load_optimizer_state(file, m_pending_optim_sum);
    }
    if (m_resid.defined() && m_resid_file.empty()) return;
    auto r = m_data->clip_array({m_data->frames, 1, m_data->height, m_data->width});
    if (m_resid.defined())
        for (int s = 0; s < m_data->frames; ++s) r[s].copy_(residual_frame(s));
    else
        r.fill_(-1.0f);
    std::lock_guard<std::mutex> lock(m_unexplained_mutex);  // readers hold it (fallback_weight)
    m_resid = r;
    m_resid_file.clear();
}

void FitEngine::step() {
    if (done()) return;
    finish_restore();
    const auto t0 = Clock::now();
    LossTerms terms;
    double loss_v = 0.0, psnr_v = 0.0;
    if (m_model->steps_itself()) {
        m_model->step_itself(m_step, m_model_mutex);
        torch::NoGradGuard g;
        std::vector<int64_t> f{m_step};
        Layers L;
        {
            std::lock_guard<std::mutex> lock(m_model_mutex);
            L = m_model->render(f);
        }
        auto rb = srgb_encode(reblur(L, f));
        auto target = srgb_encode(m_data->input[m_step].unsqueeze(0));
        double mse = (rb - target).pow(2).mean().item<double>();
        psnr_v = 10 * std::log10(1.0 / std::max(mse, 1e-12));
        terms["reco_mse"] = mse;
        loss_v = mse;
    } else {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        // Learning rate: cosine decay to lr_floor over the budget; a crop step's times its
        // share of the frame to the power crop_lr_power (docs/method.md, Crops).
        StageClock clock;  // --debug timing
        clock.next("step: frames and crops");
        auto frames = next_batch();
        const Crops crops = step_crops(frames);
        const double frac = budget_fraction();
        const double fl = m_opts.lr_floor;
        double factor = fl + (1.0 - fl) * 0.5 * (1.0 + std::cos(M_PI * frac));
        if (!crops.whole)
            factor *= std::pow(double(crops.w * crops.h) / double(m_data->width * m_data->height),
                               m_opts.crop_lr_power);
        auto& groups = m_optim->param_groups();
        for (size_t i = 0; i < groups.size(); ++i)
            static_cast<torch::optim::AdamOptions&>(groups[i].options()).lr(m_base_lr[i] * factor);

        StepRender r;
        clock.next("step: render and reblur");
        try {
            r = render_step(frames, crops);
        } catch (const Error&) {
            // An update that left NaN/Inf in the state is refused by the blur's own check:
            // said as what it is, a fit that diverged.
            for (auto& [name, t] : m_model->state())
                if (t.is_floating_point() && !torch::isfinite(t).all().item<bool>())
                    throw Error("fit: diverging at step " + std::to_string(m_step) +
                                ": the model's " + name + " holds NaN/Inf" + kDivergedAdvice);
            throw;
        }
        const torch::Tensor& rb = r.reblur;
        const torch::Tensor& target = r.target;
        clock.next("step: robust weights");
        auto fit_target = robust_target(rb, target, frames, r.scored);
        clock.next("step: losses and priors");
        auto l1 = (rb - fit_target).abs().mean();
        auto ms = ms_ssim_loss(rb, fit_target);
        auto reco = (1.0 - m_opts.ms_ssim_share) * l1 + m_opts.ms_ssim_share * ms;
        auto loss = m_opts.w_reco * reco + m_model->priors(r.trained, frames, m_step, terms);
        check_divergence(loss.item<double>());  // before the update: the state stays the last good
        clock.next("step: backward");
        m_optim->zero_grad();
        loss.backward();
        clock.next("step: optimizer");
        m_optim->step();
        clock.next("step: figures");
        terms["l1"] = l1.item<double>();
        terms["ms_ssim"] = 1.0 - ms.item<double>();
        loss_v = loss.item<double>();
        double mse = (rb.detach() - target).pow(2).mean().item<double>();
        psnr_v = 10 * std::log10(1.0 / std::max(mse, 1e-12));
    }
    if (m_step < 2) debug_memory(m_step == 0 ? "engine: first step" : "engine: second step");
    ++m_step;
    m_elapsed += std::chrono::duration<double>(Clock::now() - t0).count();
    if (timing_enabled())
        add_timing("step (all)", std::chrono::duration<double>(Clock::now() - t0).count());

    // How well the fit explains the clip, for the studio (a measure over 32 frames: not at
    // every step).
    double rms = std::numeric_limits<double>::quiet_NaN(), trust = 0;
    const bool measure = m_step % 25 == 0 || done();
    if (measure) rms = residual_rms(), trust = reported_trust();
    std::lock_guard<std::mutex> lock(m_snap_mutex);
    if (measure) m_snap.residual_rms = rms, m_snap.trust = trust;
    m_snap.step = m_step;
    m_snap.loss = loss_v;
    m_snap.terms = terms;
    m_snap.reblur_psnr = psnr_v;
    m_snap.elapsed_s = m_elapsed;
    const double frac =
        m_model->steps_itself() ? double(m_step) / m_model->step_count() : budget_fraction();
    m_snap.progress = frac;
    m_snap.eta_s = frac > 0 ? m_elapsed * (1.0 - frac) / frac : -1.0;
    m_snap.atlas_version++;
    m_snap.status = done() ? (m_stop ? "stopped" : "done") : (m_paused ? "paused" : "running");
}

std::string loss_divergence(const std::deque<double>& recent, double loss) {
    if (!std::isfinite(loss)) return "the loss became NaN/Inf";
    constexpr size_t kMinSeen = 8;
    constexpr double kGrowth = 100.0;
    if (recent.size() < kMinSeen) return "";
    std::vector<double> v(recent.begin(), recent.end());
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    const double median = v[v.size() / 2];
    if (!(median > 0) || loss <= kGrowth * median) return "";
    char b[160];
    std::snprintf(b, sizeof b, "diverging: the loss is %.3g, %.0fx its running median %.3g", loss,
                  loss / median, median);
    return b;
}

void FitEngine::check_divergence(double loss) {
    // A fit that diverges (a damaged state, absurd input) stops before its update: the caller
    // saves nothing, and the last checkpoint stays the last good state.
    const std::string why = loss_divergence(m_recent_loss, loss);
    if (!why.empty())
        throw Error("fit: " + why + " at step " + std::to_string(m_step) + kDivergedAdvice);
    constexpr size_t kWindow = 31;
    m_recent_loss.push_back(loss);
    if (m_recent_loss.size() > kWindow) m_recent_loss.pop_front();
}

FitSnapshot FitEngine::snapshot() const {
    std::lock_guard<std::mutex> lock(m_snap_mutex);
    return m_snap;
}

Layers FitEngine::render_frame(int t) {
    if (t < 0 || t >= m_data->frames) throw Error("frame " + std::to_string(t) + " out of range");
    return rendered_layers(t);
}

Layers FitEngine::rendered_layers(int t) const {
    const int64_t step = m_step;
    {
        std::lock_guard<std::mutex> lock(m_rendered_mutex);
        for (const auto& r : m_rendered)
            if (r.frame == t && r.step == step) return r.layers;
    }
    torch::NoGradGuard g;
    Layers L;
    {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        L = m_model->render({t});
    }
    // The frames of one output-rule window and the next: at 1080p a frame's layers are 116 MB.
    const size_t keep = size_t(std::max(m_opts.fallback_frames, 0) + 2);
    std::lock_guard<std::mutex> lock(m_rendered_mutex);
    while (!m_rendered.empty() && (m_rendered.size() >= keep || m_rendered.front().step != step))
        m_rendered.pop_front();
    m_rendered.push_back({t, step, L});
    return L;
}

}  // namespace refocus
