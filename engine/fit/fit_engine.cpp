#include "fit/fit_engine.h"

#include <torch/optim.h>
#include <torch/serialize.h>
#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <cstdlib>
#include <sstream>

#include "fit/fast_model.h"
#include "fit/losses.h"
#include "fit/paper_model.h"
#include "fit/perframe.h"
#include "fit/stack_coc.h"
#include "fit/tensor_image.h"
#include "io/image_file.h"
#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

using Clock = std::chrono::steady_clock;

std::unique_ptr<FitModel> make_model(const std::string& preset, const FitData& data, uint64_t seed) {
    torch::manual_seed(seed);
    if (preset == "fast") {
        FastModelOptions o;
        // Tuning hooks for the benches (documented in README): REFOCUS_FAST_<NAME>=value.
        auto env = [](const char* name, double& v) {
            if (const char* e = std::getenv(name)) v = std::atof(e);
        };
        env("REFOCUS_FAST_LR_ATLAS", o.lr_atlas);
        env("REFOCUS_FAST_LR_WARP", o.lr_warp);
        env("REFOCUS_FAST_W_TV", o.w_tv);
        env("REFOCUS_FAST_TV_RADIUS_CAP", o.tv_radius_cap);
        env("REFOCUS_FAST_TV_RADIUS_GAIN", o.tv_radius_gain);
        env("REFOCUS_FAST_TV_RADIUS_SPREAD", o.tv_radius_spread);
        env("REFOCUS_FAST_TV_RADIUS_FADE", o.tv_radius_fade);
        env("REFOCUS_FAST_TV_RADIUS_LAYERS", o.tv_radius_layers);
        env("REFOCUS_FAST_W_WARP", o.w_warp);
        env("REFOCUS_FAST_W_TEMPORAL", o.w_temporal);
        env("REFOCUS_FAST_W_ALPHA_RESIDUAL", o.w_alpha_residual);
        env("REFOCUS_FAST_ALPHA_SHARED_LR", o.alpha_shared_lr);
        env("REFOCUS_FAST_LR_ALPHA", o.lr_alpha);
        env("REFOCUS_FAST_W_BOOTSTRAP", o.w_bootstrap);
        double deblur = o.deblur_path;
        env("REFOCUS_FAST_DEBLUR_PATH", deblur);
        o.deblur_path = deblur != 0;
        env("REFOCUS_FAST_DEBLUR_EPS", o.deblur_eps);
        env("REFOCUS_FAST_DEBLUR_LR", o.deblur_lr);
        env("REFOCUS_FAST_DEBLUR_MIN_RADIUS", o.deblur_min_radius);
        double dbatch = o.deblur_batch;
        env("REFOCUS_FAST_DEBLUR_BATCH", dbatch);
        o.deblur_batch = std::max(1, int(dbatch));
        // Half the TV where the path's layer has a given radius (synth walkout, true radius: 10 min
        // 21.30 -> 21.57 dB); an estimate's errors want the full TV (walkout, estimated radius,
        // 600 steps: 20.18 / tPSNR 25.75 at 1.0, 20.10 / 25.48 at 0.5). README, "What the table says".
        o.deblur_tv = data.radius_given ? o.deblur_tv_given : o.deblur_tv;
        env("REFOCUS_FAST_DEBLUR_TV", o.deblur_tv);
        double halflife = o.bootstrap_halflife;
        env("REFOCUS_FAST_BOOTSTRAP_HALFLIFE", halflife);
        o.bootstrap_halflife = int(halflife);
        double cell = o.warp_cell_px, rounds = o.align_rounds;
        env("REFOCUS_FAST_WARP_CELL", cell);
        env("REFOCUS_FAST_ALIGN_ROUNDS", rounds);
        o.warp_cell_px = int(cell);
        o.align_rounds = int(rounds);
        // The atlases reach past the frame by the widest blur support, so that edge pixels are
        // explained by the scene beyond the edge (FitModel::render_padded).
        double pad = std::ceil(lens_blur_support(data.radius.max().item<double>(), data.blur));
        env("REFOCUS_FAST_PAD", pad);
        o.pad = int(std::clamp(pad, 0.0, 48.0));
        o.atlas_scale = data.atlas_scale;
        return std::make_unique<FastModel>(data, o);
    }
    if (preset == "paper") return std::make_unique<PaperModel>(data, PaperModelOptions{}, seed);
    if (preset == "perframe") return nullptr;  // no atlas model: see step_perframe()
    throw Error("unknown preset '" + preset + "' (use fast, paper or perframe)");
}

int checked_batch_arg(int64_t n) {
    if (n < 1) throw Error("fit: --batch must be at least 1 frame per step (got " + std::to_string(n) + ")");
    return static_cast<int>(n);
}

FitEngine::FitEngine(std::shared_ptr<FitData> data, const FitOptions& opts)
    : m_data(std::move(data)), m_opts(opts), m_rng(opts.seed) {
    // A/B hooks for the benches (README, "Measured"): REFOCUS_ROBUST_C, REFOCUS_FALLBACK_K,
    // REFOCUS_MS_SSIM_SHARE.
    if (const char* e = std::getenv("REFOCUS_ROBUST_C")) m_opts.robust_c = std::atof(e);
    if (const char* e = std::getenv("REFOCUS_FALLBACK_K")) m_opts.fallback_k = std::atof(e);
    if (const char* e = std::getenv("REFOCUS_MS_SSIM_SHARE")) m_opts.ms_ssim_share = std::atof(e);
    if (const char* e = std::getenv("REFOCUS_LR_FLOOR")) m_opts.lr_floor = std::atof(e);
    if (!m_data || m_data->frames <= 0) throw Error("fit: the clip has no frames");
    if (m_opts.minutes <= 0 && m_opts.iters <= 0)
        throw Error("fit: give a budget (--minutes M or --iters N)");
    if (m_opts.batch < 0) checked_batch_arg(m_opts.batch);  // 0: the model's choice
    if (!torch::isfinite(m_data->input).all().item<bool>())
        throw Error("fit: the input frames contain NaN/Inf");
    if (!torch::isfinite(m_data->radius).all().item<bool>() ||
        (m_data->radius < 0).any().item<bool>())
        throw Error("fit: the radius maps contain NaN/Inf or negative values");
    {
        torch::NoGradGuard g;
        m_target = srgb_encode(m_data->input);
        m_resid = torch::full({m_data->frames, 1, m_data->height, m_data->width}, -1.0f);
    }
    if (m_opts.preset == "perframe") {  // no atlas model: see step_perframe()
        m_perframe = m_data->input.clone();
        m_perframe_done.assign(m_data->frames, false);
        return;
    }
    build_model();
}

void FitEngine::build_model() {
    bool on = m_opts.layer_radius;
    if (const char* e = std::getenv("REFOCUS_LAYER_RADIUS")) on = std::atoi(e) != 0;  // A/B hook
    if (on) split_radius_by_layer(*m_data);
    else m_data->radius_fg = m_data->radius_bg = torch::Tensor();
    m_model = make_model(m_opts.preset, *m_data, m_opts.seed);
    if (const char* e = std::getenv("REFOCUS_DEBUG_INIT_ATLAS")) {
        // Diagnostic: start from given atlases (<dir>/atlas_bg.exr, and atlas_fg.exr where the
        // file is there), e.g. the ground truth splatted through a fitted project's UV, to see
        // where the objective's own optimum lies (README, Known limits: walkout).
        const std::string dir = e;
        m_model->set_atlas_bg(image_to_tensor(read_image_file(dir + "/atlas_bg.exr").image));
        if (std::filesystem::exists(dir + "/atlas_fg.exr"))
            m_model->set_atlas_fg(image_to_tensor(read_image_file(dir + "/atlas_fg.exr").image));
    }
    m_batch = m_opts.batch > 0 ? m_opts.batch : m_model->preferred_batch();
    if (m_opts.batch == 0 && m_batch != 2)
        m_model->notes.push_back("fit: " + std::to_string(m_batch) + " frames a step (" +
                                 m_model->preferred_batch_reason() + ")");
    m_pad = m_model->max_pad();
    if (m_pad > 0) {
        auto padded = [&](const torch::Tensor& r) {
            return F::pad(r.unsqueeze(1), F::PadFuncOptions({m_pad, m_pad, m_pad, m_pad}).mode(torch::kReplicate))
                .squeeze(1);
        };
        m_radius_pad = padded(m_data->radius);
        m_radius_fg_pad = padded(m_data->layer_radius(true));
        m_radius_bg_pad = padded(m_data->layer_radius(false));
    }
    make_optimizer();
}

FitEngine::~FitEngine() = default;

const std::vector<std::string>& FitEngine::model_notes() const {
    static const std::vector<std::string> none;  // perframe has no model
    return m_model ? m_model->notes : none;
}

void FitEngine::make_optimizer() {
    std::vector<torch::optim::OptimizerParamGroup> groups;
    m_base_lr.clear();
    for (auto& g : m_model->param_groups()) {
        groups.emplace_back(g.params, std::make_unique<torch::optim::AdamOptions>(g.lr));
        m_base_lr.push_back(g.lr);
    }
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
    if (!m_model) return m_step >= m_data->frames || budget_fraction() >= 1.0;
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

torch::Tensor FitEngine::reblur(const Layers& L, const std::vector<int64_t>& frames) {
    // Layers rendered with a margin (render_padded) are blurred with the radius maps padded
    // alike and cropped back to the frame.
    const int64_t pad = (L.sharp.size(3) - m_data->width) / 2;
    if (pad != 0 && pad != m_pad) throw Error("reblur: layers padded by an unexpected margin");
    std::vector<torch::Tensor> out;
    for (size_t b = 0; b < frames.size(); ++b) {
        const int64_t t = frames[b];
        if (!L.fg.defined()) {
            auto r = pad ? m_radius_pad[t] : m_data->radius[t];
            out.push_back(lens_blur(L.sharp[b], r, m_data->blur));  // paper eq. 3
            continue;
        }
        // Layered reblur L(α·F) + (1 − L(α))·L(B): α·F and α scatter with the subject's radius,
        // B with the wall's (the same map for both unless split_radius_by_layer gave two, then
        // two passes).
        auto a = L.alpha[b];
        auto rf = pad ? m_radius_fg_pad[t] : m_data->layer_radius(true)[t];
        auto rb = pad ? m_radius_bg_pad[t] : m_data->layer_radius(false)[t];
        if (m_data->radius_fg.defined()) {
            auto blf = lens_blur(torch::cat({a * L.fg[b], a}, 0), rf, m_data->blur);
            auto blb = lens_blur(L.bg[b], rb, m_data->blur);
            out.push_back(blf.narrow(0, 0, 3) + (1.0 - blf.narrow(0, 3, 1)) * blb);
            continue;
        }
        auto bl = lens_blur(torch::cat({a * L.fg[b], a, L.bg[b]}, 0), rf, m_data->blur);  // one 7-channel pass
        out.push_back(bl.narrow(0, 0, 3) + (1.0 - bl.narrow(0, 3, 1)) * bl.narrow(0, 4, 3));
    }
    auto rb = torch::stack(out);
    return pad ? rb.narrow(2, pad, m_data->height).narrow(3, pad, m_data->width) : rb;
}

torch::Tensor FitEngine::robust_target(const torch::Tensor& rb, const torch::Tensor& target,
                                       const std::vector<int64_t>& frames) {
    const bool robust = m_opts.robust_c > 0;
    if (!robust && !(m_opts.fallback_k > 0)) return target;  // nothing needs the residual
    torch::NoGradGuard no_grad;
    // Residual of this step, smoothed over 5x5 px (a single pixel's error is noise), folded into
    // the frame's running residual (the atlases move slowly; one step's error alone flickers).
    auto e = (rb.detach() - target).abs().mean(1, true);
    e = F::avg_pool2d(F::pad(e, F::PadFuncOptions({2, 2, 2, 2}).mode(torch::kReplicate)),
                      F::AvgPool2dFuncOptions(5).stride(1));
    std::vector<torch::Tensor> w;
    for (size_t b = 0; b < frames.size(); ++b) {
        auto r = m_resid[frames[b]];
        auto fresh = e[b];
        r.copy_(torch::where(r < 0, fresh, 0.7 * r + 0.3 * fresh));
        if (!robust) continue;
        const double scale = std::max(r.median().item<double>(), 1e-4);
        w.push_back(1.0 / (1.0 + (r / (m_opts.robust_c * scale)).pow(2)));
    }
    if (!robust || m_step < m_opts.robust_warmup) return target;
    // Where the weight is low the target becomes the current reblur: no gradient from there,
    // for the L1 and the MS-SSIM terms alike.
    auto wt = torch::stack(w);
    return wt * target + (1.0 - wt) * rb.detach();
}

void FitEngine::step_perframe() {
    // The baseline: non-blind MAP deconvolution with a TV prior, one frame per step.
    const int64_t t = m_step;
    TvDeconvOptions o;
    o.blur = m_data->blur;
    // 50 ADMM iterations: ~0.3 dB short of convergence on textured frames but ~5x faster
    // (converged runs take 5–9 min per 320x180 frame on 2 cores; see tests/test_perframe.cpp).
    o.iterations = 50;
    // λ for real footage, not for clean renders: the blur model never matches a lens exactly
    // (the lens blur layer reblurs the ground truth of the synth clips to only 31-36 dB PSNR),
    // and that mismatch is the "noise" TV must absorb. Sweep on the synth tripod clip, frames
    // 3/15/24, 50 iterations (sharp PSNR, input 21.56/16.40/21.11 dB):
    //   estimated radius, frames 3/15: λ 2e-3: 20.99/15.03 · 5e-3: 21.84/16.00 · 1e-2: 22.12/16.32
    //                                  · 2e-2: 21.97/16.40 · 4e-2: 21.37/16.37 (λ 1e-4: ~15 dB on the clip)
    //   true radius:                λ 2e-3: 19.57/14.65/18.93 · 1e-2: 21.11/16.15/20.85 · 2e-2: 21.38/16.31/20.87
    // Eleventh session, the pillbox with the coc conversion counting the pixel grid, rack frames
    // 0-5 (the clip's PSNR with the rest as shot): estimated radius λ 1e-2: 20.85 · 3e-3: 20.56
    // · 1e-3: 19.90 (SSIM rises as λ falls: 0.698 · 0.723 · 0.753); true radius 1e-2: 20.27 ·
    // 3e-3: 19.69. λ stays.
    o.lambda = 0.01;
    if (const char* e = std::getenv("REFOCUS_PERFRAME_LAMBDA")) o.lambda = std::atof(e);  // A/B hook
    auto u = deconvolve_tv(m_data->input[t], m_data->radius[t], o);
    std::lock_guard<std::mutex> lock(m_model_mutex);
    m_perframe[t].copy_(u);
    m_perframe_done[t] = true;
}

void FitEngine::step() {
    if (done()) return;
    const auto t0 = Clock::now();
    LossTerms terms;
    double loss_v = 0.0, psnr_v = 0.0;
    if (!m_model) {
        step_perframe();
        torch::NoGradGuard g;
        std::vector<int64_t> f{m_step};
        Layers L;
        L.sharp = m_perframe[m_step].unsqueeze(0);
        auto rb = srgb_encode(reblur(L, f));
        double mse = (rb - m_target[m_step].unsqueeze(0)).pow(2).mean().item<double>();
        psnr_v = 10 * std::log10(1.0 / std::max(mse, 1e-12));
        terms["reco_mse"] = mse;
        loss_v = mse;
    } else {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        // Learning rate: cosine decay to lr_floor over the budget.
        const double frac = budget_fraction();
        const double fl = m_opts.lr_floor;
        const double factor = fl + (1.0 - fl) * 0.5 * (1.0 + std::cos(M_PI * frac));
        auto& groups = m_optim->param_groups();
        for (size_t i = 0; i < groups.size(); ++i)
            static_cast<torch::optim::AdamOptions&>(groups[i].options()).lr(m_base_lr[i] * factor);

        auto frames = next_batch();
        Layers L = m_model->render_padded(frames, m_pad);
        auto rb = srgb_encode(reblur(L, frames));
        auto idx = torch::tensor(frames, torch::kLong);
        auto target = m_target.index_select(0, idx);
        auto fit_target = robust_target(rb, target, frames);
        auto l1 = (rb - fit_target).abs().mean();
        auto ms = ms_ssim_loss(rb, fit_target);
        auto reco = (1.0 - m_opts.ms_ssim_share) * l1 + m_opts.ms_ssim_share * ms;
        auto loss = m_opts.w_reco * reco + m_model->priors(L, frames, m_step, terms);
        if (!torch::isfinite(loss).item<bool>())
            throw Error("fit: the loss became NaN/Inf at step " + std::to_string(m_step));
        m_optim->zero_grad();
        loss.backward();
        m_optim->step();
        terms["l1"] = l1.item<double>();
        terms["ms_ssim"] = 1.0 - ms.item<double>();
        loss_v = loss.item<double>();
        double mse = (rb.detach() - target).pow(2).mean().item<double>();
        psnr_v = 10 * std::log10(1.0 / std::max(mse, 1e-12));
    }
    ++m_step;
    m_elapsed += std::chrono::duration<double>(Clock::now() - t0).count();

    std::lock_guard<std::mutex> lock(m_snap_mutex);
    m_snap.step = m_step;
    m_snap.loss = loss_v;
    m_snap.terms = terms;
    m_snap.reblur_psnr = psnr_v;
    m_snap.elapsed_s = m_elapsed;
    const double frac = m_model ? budget_fraction() : double(m_step) / m_data->frames;
    m_snap.progress = frac;
    m_snap.eta_s = frac > 0 ? m_elapsed * (1.0 - frac) / frac : -1.0;
    m_snap.atlas_version++;
    m_snap.status = done() ? (m_stop ? "stopped" : "done") : (m_paused ? "paused" : "running");
}

FitSnapshot FitEngine::snapshot() const {
    std::lock_guard<std::mutex> lock(m_snap_mutex);
    return m_snap;
}

Layers FitEngine::render_frame(int t) {
    if (t < 0 || t >= m_data->frames) throw Error("frame " + std::to_string(t) + " out of range");
    torch::NoGradGuard g;
    std::lock_guard<std::mutex> lock(m_model_mutex);
    if (!m_model) {
        Layers L;
        L.sharp = m_perframe[t].unsqueeze(0).clone();
        L.bg = L.sharp;
        return L;
    }
    return m_model->render({t});
}

torch::Tensor FitEngine::fallback_weight(int t) const {
    if (!m_model || !(m_opts.fallback_k > 0) || t < 0 || t >= m_data->frames) return {};
    torch::NoGradGuard g;
    auto r = m_resid[t].unsqueeze(0);  // [1,1,H,W]
    if ((r < 0).any().item<bool>()) return {};
    const double lo = std::max(m_opts.fallback_k * r.median().item<double>(), m_opts.fallback_min);
    auto x = ((r - lo) / lo).clamp(0, 1);
    auto f = x * x * (3 - 2 * x);  // smoothstep(lo, 2·lo)
    // Opened by 9 px: the thin band along an occlusion edge that one layer explains poorly is
    // still better fitted than the shot (it would flicker between the two); a subject the masks
    // missed is a region.
    const int e = 4;
    if (e > 0) {
        f = -F::max_pool2d(-f, F::MaxPool2dFuncOptions(2 * e + 1).stride(1).padding(e));
        f = F::max_pool2d(f, F::MaxPool2dFuncOptions(2 * e + 1).stride(1).padding(e));
    }
    // Grown and feathered by 4 px: the residual is lowest at the middle of a flat region that
    // is wrong all the same, and a hard seam would show.
    f = F::max_pool2d(f, F::MaxPool2dFuncOptions(9).stride(1).padding(4));
    f = F::avg_pool2d(F::pad(f, F::PadFuncOptions({4, 4, 4, 4}).mode(torch::kReplicate)),
                      F::AvgPool2dFuncOptions(9).stride(1));
    if (!(f > 1e-3).any().item<bool>()) return {};
    return f;
}

void FitEngine::apply_fallback(Layers& L, int t, const torch::Tensor& model_sharp) const {
    auto f = fallback_weight(t);
    if (!f.defined() || !L.sharp.defined()) return;
    torch::NoGradGuard g;
    auto in = m_data->input[t].unsqueeze(0);
    if (model_sharp.defined())
        L.sharp = (1.0 - f) * model_sharp + f * in + (L.sharp - model_sharp);
    else
        L.sharp = (1.0 - f) * L.sharp + f * in;
}

// ---------------------------------------------------------------- checkpoints
namespace {
constexpr int kCheckpointVersion = 1;
const char* kernel_name(const LensBlurParams& p) {
    return p.kernel == BlurKernel::Pillbox ? "pillbox" : p.kernel == BlurKernel::Disk ? "disk" : "gaussian";
}
}

bool FitEngine::has_checkpoint(const fs::path& dir) { return fs::exists(dir / "checkpoint.json"); }

void FitEngine::save_checkpoint(const fs::path& dir) {
    fs::create_directories(dir);
    const std::string pt_name = "checkpoint_" + std::to_string(m_step) + ".pt";
    const fs::path pt = dir / pt_name;
    {
        std::lock_guard<std::mutex> lock(m_model_mutex);
        torch::serialize::OutputArchive ar;
        if (m_model) {
            for (auto& [name, t] : m_model->state()) ar.write("model/" + name, t.detach());
            ar.write("robust_resid", m_resid);
            torch::serialize::OutputArchive opt;
            m_optim->save(opt);
            ar.write("optimizer", opt);
        } else {
            ar.write("perframe", m_perframe);
        }
        fs::path tmp = temp_sibling(pt);
        try {
            ar.save_to(tmp.string());
        } catch (const std::exception& e) {
            std::error_code ec;
            fs::remove(tmp, ec);
            throw Error(file_error(pt.string(), std::string("cannot write checkpoint: ") + e.what()));
        }
        commit_temp(tmp, pt);
    }
    std::ostringstream rng;
    rng << m_rng;
    FitSnapshot last = snapshot();  // the last step's figures, shown again after a reopen
    nlohmann::json j = {{"version", kCheckpointVersion},
                        {"loss", last.loss},
                        {"reblur_psnr", last.reblur_psnr},
                        {"terms", last.terms},
                        {"preset", m_opts.preset},
                        {"frames", m_data->frames},
                        {"height", m_data->height},
                        {"width", m_data->width},
                        {"two_layers", m_data->has_subject},
                        {"subject_track", m_data->legacy_subject_track ? "centroid" : m_data->legacy_track_gaps ? "flow" : "flow-v2"},
                        {"kernel", kernel_name(m_data->blur)},
                        {"atlas_scale", m_data->atlas_scale},
                        {"step", m_step},
                        {"elapsed_s", m_elapsed},
                        {"seed", m_opts.seed},
                        {"rng", rng.str()},
                        {"perm", m_perm},
                        {"perm_pos", m_perm_pos},
                        {"perframe_done", m_perframe_done},
                        {"tensors", pt_name}};
    write_file_atomic(dir / "checkpoint.json", j.dump(1));
    // Older tensor files are no longer referenced.
    for (const auto& e : fs::directory_iterator(dir)) {
        const std::string n = e.path().filename().string();
        if (n.rfind("checkpoint_", 0) == 0 && n != pt_name && e.path().extension() == ".pt") {
            std::error_code ec;
            fs::remove(e.path(), ec);
        }
    }
    m_last_ckpt = m_elapsed;
}

bool FitEngine::maybe_checkpoint(const fs::path& dir) {
    if (m_elapsed - m_last_ckpt < m_opts.checkpoint_seconds) return false;
    save_checkpoint(dir);
    return true;
}

void FitEngine::load_checkpoint(const fs::path& dir) {
    const fs::path jf = dir / "checkpoint.json";
    nlohmann::json j;
    try {
        j = nlohmann::json::parse(read_text_file(jf));
    } catch (const nlohmann::json::exception& e) {
        throw Error(file_error(jf.string(), std::string("corrupt checkpoint: ") + e.what()));
    }
    auto expect = [&](const char* key, const nlohmann::json& want) {
        if (!j.contains(key) || j[key] != want)
            throw Error(file_error(jf.string(), std::string("checkpoint field '") + key + "' is " +
                                                    (j.contains(key) ? j[key].dump() : "missing") +
                                                    ", this fit has " + want.dump()));
    };
    if (j.value("version", 0) > kCheckpointVersion)
        throw Error(file_error(jf.string(), "checkpoint from a newer Refocus"));
    expect("preset", m_opts.preset);
    expect("frames", m_data->frames);
    expect("height", m_data->height);
    expect("width", m_data->width);
    // The radius and the reblur are in the kernel's terms (checkpoints before the tenth session:
    // the paper's disk; the project's fit settings say which kernel to set the data up with).
    if (!j.contains("kernel")) j["kernel"] = "disk";
    expect("kernel", kernel_name(m_data->blur));
    const fs::path pt = dir / j.value("tensors", std::string());
    torch::serialize::InputArchive ar;
    try {
        ar.load_from(pt.string());
    } catch (const std::exception& e) {
        throw Error(file_error(pt.string(), "cannot read checkpoint tensors (truncated?)"));
    }
    std::lock_guard<std::mutex> lock(m_model_mutex);
    if (m_model) {
        // A checkpoint of an earlier build placed the subject's atlas on its masks' centroids:
        // the model is rebuilt that way, so that its atlases and mappings mean what they meant.
        // "flow" (eighth session) chained the subject's flow over the masks as stored; "flow-v2"
        // (ninth) cleans the masks along the track first (clean_subject_masks) and steps over a
        // missing mask at the previous step's pace.
        const std::string kind = j.value("subject_track", std::string("centroid"));
        const bool legacy = m_data->has_subject && kind == "centroid";
        const bool legacy_gaps = m_data->has_subject && kind != "flow-v2";
        // The atlas resolution the fit trained (checkpoints before the twelfth session: 1x).
        const double scale = j.value("atlas_scale", 1.0);
        if (!(scale >= 1 && scale <= 4))
            throw Error(file_error(jf.string(), "checkpoint atlas_scale " + j["atlas_scale"].dump() + " is out of range"));
        if (legacy != m_data->legacy_subject_track || legacy_gaps != m_data->legacy_track_gaps ||
            scale != m_data->atlas_scale) {
            m_data->atlas_scale = scale;
            m_data->legacy_subject_track = legacy;
            m_data->legacy_track_gaps = legacy_gaps;
            if (legacy_gaps && m_data->mask_as_stored.defined()) m_data->mask = m_data->mask_as_stored;
            build_model();
        }
        std::map<std::string, torch::Tensor> s;
        for (auto& [name, t] : m_model->state()) {
            torch::Tensor v;
            if (ar.try_read("model/" + name, v)) s[name] = v;  // the model says what it cannot lack
        }
        try {
            m_model->load_state(s);
        } catch (const Error& e) {
            throw Error(file_error(pt.string(), e.what()));
        }
        make_optimizer();  // load_state may have given the model new tensors (a stored geometry)
        torch::Tensor resid;  // older checkpoints lack it: the running residual starts again
        if (ar.try_read("robust_resid", resid) && resid.sizes().equals(m_resid.sizes())) m_resid.copy_(resid);
        torch::serialize::InputArchive opt;
        ar.read("optimizer", opt);
        m_optim->load(opt);
    } else {
        torch::Tensor v;
        ar.read("perframe", v);
        if (!v.sizes().equals(m_perframe.sizes()))
            throw Error(file_error(pt.string(), "perframe tensor has the wrong shape"));
        m_perframe.copy_(v);
        m_perframe_done = j.at("perframe_done").get<std::vector<bool>>();
    }
    m_step = j.at("step").get<int64_t>();
    m_elapsed = j.at("elapsed_s").get<double>();
    m_last_ckpt = m_elapsed;
    std::istringstream rng(j.at("rng").get<std::string>());
    rng >> m_rng;
    m_perm = j.at("perm").get<std::vector<int64_t>>();
    m_perm_pos = j.at("perm_pos").get<size_t>();
    std::lock_guard<std::mutex> l2(m_snap_mutex);
    m_snap.step = m_step;
    m_snap.elapsed_s = m_elapsed;
    // Older checkpoints lack the figures: they stay 0 until the next step.
    m_snap.loss = j.value("loss", 0.0);
    m_snap.reblur_psnr = j.value("reblur_psnr", 0.0);
    if (j.contains("terms") && j["terms"].is_object()) m_snap.terms = j["terms"].get<LossTerms>();
    m_snap.atlas_version++;
}

}  // namespace refocus
