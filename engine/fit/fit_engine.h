#pragma once
// The fit engine: one object driven by step(), shared by the CLI, the studio and the tests.
// It minimises  Σ_t ‖L(C_t, r_t) − I_t‖ + priors  (docs/method.md, Objective; paper eq. 3 and 4)
// over a FitModel, with a layered reblur: L(α·F) + (1 − L(α))·L(B), so that a blurred foreground
// edge reveals the background the atlas holds behind it (docs/method.md, Layered reblur).
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <deque>
#include <limits>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include "model/fit_model.h"
#include "fit/confidence.h"
#include "fit/crops.h"
#include "fit/presets.h"
#include "fit/settings.h"
#include "ops/lens_blur.h"

namespace torch::optim {
class Optimizer;
}

namespace refocus {

struct FitOptions {
    std::string preset = "fast";  // fast | paper | perframe
    double minutes = 0.0;         // time budget (0: none)
    int64_t iters = 0;            // step budget (0: none); one of the two must be set
    uint64_t seed = 1;
    int batch = 0;                // frames per step; 0: the model's (FitModel::preferred_batch)
    double w_reco = 1.0;          // λ1 of paper eq. 4 (others live in the models)
    double ms_ssim_share = 0.84;  // L_reco = 0.84·(1 − MS-SSIM) + 0.16·L1 (Zhao et al. 2016)
    double lr_floor = 0.1;        // the learning rate decays (cosine) to this share of its own
    double checkpoint_seconds = 60.0;
    // Robust reconstruction (IRLS, Geman-McClure weights): pixels whose reblur residual stays
    // far above their frame's typical residual — what the model cannot explain (an occlusion
    // edge fitted as one layer, a mask that misses the subject) — stop pulling on the atlases.
    // Weight 1 / (1 + (e / (c · median_t e))²) of a running residual e; 0 turns it off.
    // A smaller c scores higher on the synth clips; 1.5 keeps most pixels near full weight on
    // footage they do not represent (docs/method.md, Robust weights).
    double robust_c = 1.5;
    int64_t robust_warmup = 60;  // steps before the weights apply (the first fit is blurry)
    // Fallback (FitEngine::fallback_weight): from `fallback_k` x the frame's median residual
    // (and at least `fallback_min`, sRGB) the input shows through, fully at twice that.
    double fallback_k = 1.0;
    double fallback_min = 0.01;
    int fallback_frames = 2;  // smooth in time: grown over ±n frames, then averaged over ±n
    // The evidence rule (confidence.h, unexplained_share_evidence) in place of the median's:
    // unexplained where the residual passes 0.8·σ (the clip's measured noise) plus this share of
    // what the model changes over its own reblur, plus `fallback_floor` (sRGB). 0: the median
    // rule (fallback_k, fallback_min).
    double fallback_change = 0.35;
    double fallback_floor = 0.008;
    // Where the fit is trusted (model_trust), the evidence rule's floor rises to this many
    // times the clip's residual RMS over the noise: a residual the fit leaves everywhere is its
    // own, not a wrong model's (0: off).
    double trusted_residual = 1.5;
    // Nothing to fix: where no blur of at least this radius (px) reaches a pixel, the output is
    // the shot (0: off).
    double keep_focus_px = 0.5;
    // Low-frequency lock (confidence.h, lock_low_frequencies): below this Gaussian scale (px)
    // the plate takes the input's content, since a blur keeps local means and a colour or
    // exposure shift is never a deblur (0: off).
    double lock_low_px = 2.0;
    // A fit that explains the clip (FitEngine::model_trust): its reblur residual's RMS over the
    // noise's under this many 8-bit levels (0: never trusted). Its low-frequency lock then reads
    // the model's reblur, which γ keeps to where another frame saw sharper (docs/method.md).
    double explained_rms = 3.5;
    // Where the fit is trusted, the model also replaces a pixel that no frame saw sharper where
    // the blur reaches twice this (px), none under it (smoothstep). 0 (the default): never; a
    // long fit of a wrong radius or lens reaches a low residual too.
    double trusted_blur_px = 0.0;
    // Seen sharp (confidence.h, seen_trust): the model restores a pixel fully where some frame
    // saw it blurred by at most this radius (px), and not from twice that: detail no frame
    // recorded comes from deconvolution alone (0: trust it everywhere).
    double trust_seen_px = 2.0;
    // Sharper view (confidence.h, sharper_view): the model replaces frame t's pixel only where
    // some frame saw it sharper than frame t did, by more than this (px), fully from twice
    // that: where frame t is its own sharpest view, the atlas has no detail the shot lacks and
    // only deconvolution could add any (0: off; the dev half of the corpus chose 2 px).
    double sharper_view_px = 2.0;
    // Where focus moved over a point by at least `focus_moved_px` (the largest radius any frame
    // saw it at less the least, each layer its own radius; confidence.h, seen_radius), γ's
    // threshold is `sharper_view_moved_px` instead: the point was seen sharp and its radius
    // read against that view, so a small sharper view is real, not the estimate's noise (0:
    // off; chosen on the synth, real-texture and rendered dev clips, docs/benchmarks.md).
    double focus_moved_px = 4.0;
    double sharper_view_moved_px = 0.5;
    // Where a layer's focus moved as a whole by at least this (px: the range over frames of the
    // layer's median radius; confidence.h, focus_travel), a point passed over by half that
    // travel counts as moved, so a gentle rack (2-4 px) is read as one (0: off).
    double focus_travel_px = 2.0;
    // Two layers: each layer blurred with its own radius (split_radius_by_layer, stack_coc.h)
    // instead of the visible surface's map for both (docs/method.md, Layered reblur).
    bool layer_radius = true;
    // The crop step (docs/method.md, Crops): each step renders, reblurs and scores a crop of
    // about this many px a side of each frame of its batch (crops.h draws them), plus the blur's
    // margin, so that a step costs what a crop costs whatever the frame's size. An axis no
    // longer than this is kept whole: a 320x180 clip trains on whole frames. 0: whole frames
    // always (the reference path).
    int64_t crop_px = 320;
    // A crop step's learning rates are times the crop's share of the frame to this power: the
    // square-root rule for Adam (Malladi et al. 2022), measured at par with whole frames for the
    // same pixels seen (docs/method.md, Crops).
    double crop_lr_power = 0.5;
    // The settings the user changed (settings.h): the fields above (applied by FitEngine) and
    // the preset model's options (applied by its factory, presets.h).
    Settings settings;
};

// Why a step's `loss` means the fit diverges: not finite, or over 100x the median of the
// `recent` steps' (judged from 8 of them on); "" when it does not.
std::string loss_divergence(const std::deque<double>& recent, double loss);

// `--batch N` as typed: at least 1 (leaving it out lets the model choose, FitOptions::batch 0).
int checked_batch_arg(int64_t n);

struct FitSnapshot {
    int64_t step = 0;
    double loss = 0.0;
    LossTerms terms;
    double reblur_psnr = 0.0;  // of the last batch, sRGB, dB
    // FitEngine::residual_rms and model_trust, every 25 steps and at a checkpoint's load (NaN:
    // not measured yet).
    double residual_rms = std::numeric_limits<double>::quiet_NaN();
    double trust = 0.0;
    double elapsed_s = 0.0;       // training time (pauses excluded)
    double eta_s = -1.0;          // -1 when unknown
    double progress = 0.0;        // 0..1 of the budget
    int64_t atlas_version = 0;    // bumps when the atlases change
    std::string status = "idle";  // idle | running | paused | stopped | done
};

class FitEngine {
  public:
    FitEngine(std::shared_ptr<FitData> data, const FitOptions& opts);
    ~FitEngine();
    const std::vector<std::string>& model_notes() const;

    void step();  // one optimisation step (or one frame for `perframe`)
    // Whether the preset keeps atlases (perframe does not: nothing to edit or take depth from).
    bool has_atlas() const { return find_preset(m_opts.preset).has_atlas; }
    bool done() const;  // budget used up or stop requested
    // `perframe`: whether frame t has been deconvolved (frames not reached keep the input);
    // other presets: always true.
    bool frame_done(int t) const { return m_model->frame_done(t); }
    void request_stop() { m_stop = true; }
    // Sets the time budget (minutes of training; the learning-rate schedule follows it): a
    // caller that counts its own preparation and set-up in the user's budget gives the rest.
    void set_time_budget(double minutes) { m_opts.minutes = minutes; }
    void set_paused(bool p) { m_paused = p; }
    bool paused() const { return m_paused; }
    FitSnapshot snapshot() const;
    int batch() const { return m_batch; }  // frames per step, as resolved

    // Checkpoints: `dir`/checkpoint.json naming checkpoint_<step>.pt (the model),
    // checkpoint_<step>.optim.pt (the optimizer's state) and checkpoint_<step>.resid (the running
    // residual, raw float32 frames), each written atomically; the json is renamed last, so a
    // kill at any moment leaves the previous checkpoint loadable.
    void save_checkpoint(const fs::path& dir);
    // Why the checkpoint in `dir` cannot be loaded for a clip of `frames` frames (its JSON, its
    // fields, its tensor file and checksums), without building a model; "" when it can.
    static std::string checkpoint_problem(const fs::path& dir, int64_t frames);
    // The checksum checkpoint.json carries of its other fields ("checksum").
    static std::string checkpoint_json_checksum(const nlohmann::json& j);
    // How a checkpoint is opened. Train restores all a resumed fit needs. Read (export, the
    // studio's viewer) maps the running residual from its file, checking each frame's checksum
    // when it is first read, and leaves the optimizer's state on disk until a step or a save
    // needs it: at 1080p x 240 the two are 2.5 of the checkpoint's 2.8 GB.
    enum class CheckpointUse { Train, Read };
    // Restores model, optimizer, step, elapsed time and sampling state. Throws if the checkpoint
    // belongs to another preset or clip shape.
    void load_checkpoint(const fs::path& dir, CheckpointUse use = CheckpointUse::Train);
    static bool has_checkpoint(const fs::path& dir);
    // Saves when checkpoint_seconds of training time have passed after the last save.
    bool maybe_checkpoint(const fs::path& dir);

    // Inference (no gradients). Frame t's layers, its reblur, and the atlases. render_frame's
    // tensors may be shared with the recent renders kept (rendered_layers): never written in place.
    Layers render_frame(int t);
    torch::Tensor reblur(const Layers& layers,
                         const std::vector<int64_t>& frames) const;  // [B,3,H,W]
    // Never worse than the shot (fit/confidence.h; docs/method.md, Confidence and fallback).
    // fallback_weight: where frame t's reblur residual stays far above what the model explains
    // elsewhere (a subject the masks missed, ghosted over the wall; a region no mapping of the
    // atlas follows), made smooth over the neighbouring frames. [1,1,H,W] in [0,1] (1: the
    // model does not explain it), or undefined when nothing falls back (perframe, a frame not
    // trained yet, a checkpoint without the running residual).
    torch::Tensor fallback_weight(int t) const;
    // (1 − fallback_weight(t)) · τ_t, τ the seen-sharp trust (seen_trust_map): the confidence
    // pass, [1,1,H,W] (1: the model explains the region).
    torch::Tensor confidence(int t) const;
    // τ_t (confidence.h, seen_trust), undefined when fit.trust_seen_px is off. Cached: the
    // radius maps do not change while the engine lives.
    torch::Tensor seen_trust_map(int t) const;
    // The least radius any frame saw frame t's pixels at (confidence.h, sharpest_seen), cached.
    // With two layers, per layer where frame t's mask shows it: the wall's from the wall's own
    // radius through the camera, the subject's its sharpest frame (the least of its per-frame
    // medians, focus_span); a sharp subject passing over the wall is no sharp view of the wall.
    torch::Tensor sharpest_seen_map(int t) const;
    // How far focus moved over frame t's pixels: the largest radius any frame saw them at less
    // the least (confidence.h, seen_radius), cached; undefined unless fit.focus_moved_px is on.
    torch::Tensor focus_range_map(int t) const;
    // Each layer's focus_span (one for one layer; fg, bg for two).
    std::vector<FocusSpan> layer_spans(bool layered) const;
    // What the model changes over its own reblur in frame t: |C − Î| in sRGB, the mean over the
    // channels, over 5×5 px (as the running residual is read). [1,1,H,W]; renders the frame.
    torch::Tensor model_change(int t) const;
    // How well the fit explains the clip: the mean over frames (at most 32, spread over the
    // clip) of the RMS of each frame's running reblur residual (sRGB, the mean |residual| of
    // a channel over 5×5 px), in 8-bit levels. Noise of σ alone leaves 0.8σ; what the frames
    // disagree on (render noise in the blur disks, a lens that is not the model's,
    // misregistration) adds to it. NaN before any frame is measured. Cached for the step.
    double residual_rms() const;
    // 1 where the fit explains the clip (residual_rms past the noise's 0.8σ under
    // fit.explained_rms), 0 from 1.4× that (smoothstep); 0 with the setting off or no residual.
    // Where it is 1 the low-frequency lock reads the model's reblur, and with
    // fit.trusted_blur_px set γ opens where the blur reaches twice that.
    double model_trust() const;
    // model_trust as the studio and export report it: NaN with fit.explained_rms 0 (trust off).
    double reported_trust() const;
    // The model's share of the output: confidence(t) times the need (0 where no blur reaches
    // the pixel, fit.keep_focus_px) and γ_t (confidence.h, sharper_view: 1 where another frame
    // saw the pixel sharper). [1,1,H,W], undefined when it is 1 everywhere. `gamma`, when given,
    // receives γ_t (undefined when fit.sharper_view_px is off), from the same dilation.
    torch::Tensor model_weight(int t, torch::Tensor* gamma = nullptr) const;
    // L's sharp frame and layers (frame t, batch of one) blended with the input by
    // model_weight(t). When atlas edits were drawn into L, `model` is L before them: the
    // fallback blends that, and the edits stay on top (paint on the atlas shows in every frame,
    // fallback or not).
    void apply_fallback(Layers& L, int t, const Layers* model = nullptr) const;
    FitModel& model() { return *m_model; }
    const FitData& data() const { return *m_data; }
    const FitOptions& options() const { return m_opts; }
    std::mutex& model_mutex() { return m_model_mutex; }  // held during step() and renders

  private:
    // The reconstruction target with robust weights applied (see FitOptions::robust_c); updates
    // the running residual of `frames`.
    // `crops` say where rb and target lie in their frames.
    torch::Tensor robust_target(const torch::Tensor& rb, const torch::Tensor& target,
                                const std::vector<int64_t>& frames, const Crops& crops);
    // Layered reblur of the layers' frame b (frame t) with radius maps of the layers' size.
    torch::Tensor reblur_frame(const Layers& L, size_t b, int64_t t, const torch::Tensor& r,
                               const torch::Tensor& r_fg, const torch::Tensor& r_bg) const;
    // The step's crops (whole frames where crops do not apply), and the crops' reblur: the
    // layers render_window gave over `win`, reblurred and cut to the crops.
    Crops step_crops(const std::vector<int64_t>& frames) const;
    struct StepRender {
        Layers trained;        // the layers over what the step trains (the priors')
        torch::Tensor reblur;  // sRGB, over `scored`
        torch::Tensor target;  // the input there
        Crops scored;          // where the loss is taken
    };
    StepRender render_step(const std::vector<int64_t>& frames, const Crops& crops);
    torch::Tensor reblur_crops(const Layers& L, const std::vector<int64_t>& frames,
                               const Crops& crops, const Windows& win) const;
    std::vector<int64_t> next_batch();
    // Throws (the update not made) on a non-finite loss or one 100x its running median.
    void check_divergence(double loss);
    std::deque<double> m_recent_loss;  // the last steps' losses, for check_divergence
    // The model of the preset on the data (each layer's radius split first), its padded radius
    // maps and its optimiser; again when a checkpoint asks for another subject track or atlas
    // scale.
    void build_model();
    // Each layer's radius (split_radius_by_layer), or the split a long clip's last command kept.
    void split_layer_radius();
    void make_optimizer();
    // Before a step or a save: what a Read opening left on disk (the optimizer's state, the
    // residual copied out of its read-only mapping), then the residual made if there is none.
    void finish_restore();
    // m_resid[s]; a residual mapped from a checkpoint has frame s's checksum checked the first
    // time (refocus::Error naming the file on a mismatch). Undefined before the first step.
    torch::Tensor residual_frame(int s) const;
    // Reads the optimizer's state from its own archive (checkpoint.cpp), checked against `sum`.
    void load_optimizer_state(const fs::path& file, const std::string& sum);
    double budget_fraction() const;
    void step_self();  // a model that steps itself (FitModel::steps_itself)

    std::shared_ptr<FitData> m_data;
    FitOptions m_opts;
    std::unique_ptr<FitModel> m_model;
    std::unique_ptr<torch::optim::Optimizer> m_optim;
    std::vector<double> m_base_lr;
    torch::Tensor m_resid;  // [T,1,H,W] running reblur residual per pixel (-1: not yet seen)
    // A Read opening's residual file (m_resid maps it read-only) with each frame's checksum and
    // whether it was checked, and its optimizer state not read yet (file, checksum).
    fs::path m_resid_file;
    std::vector<std::string> m_resid_sums;
    mutable std::vector<char> m_resid_checked;
    mutable std::mutex m_resid_check_mutex;
    fs::path m_pending_optim;
    std::string m_pending_optim_sum;
    // Each frame's unexplained share (confidence.h) as of step m_unexplained_step: the fallback
    // of a frame reads its neighbours', and the residual only changes with a step.
    mutable std::vector<torch::Tensor> m_unexplained;
    mutable int64_t m_unexplained_step = -1;
    // model_change's last frames (the window the fallback reads around the frame asked for):
    // the change moves slowly, so a map up to kChangeSteps steps old serves a fit in progress.
    struct ChangeMap {
        int frame;
        int64_t step;
        torch::Tensor map;
    };
    mutable std::deque<ChangeMap> m_change;
    // The last frames rendered at the current step (render_frame, model_change): an export
    // renders frame t for its plate, and the output rules render t − k … t + k around it.
    struct RenderedFrame {
        int frame;
        int64_t step;
        Layers layers;
    };
    mutable std::deque<RenderedFrame> m_rendered;
    mutable std::mutex m_rendered_mutex;  // held only to look up or add, never while rendering
    Layers rendered_layers(int t) const;
    // The last frame's output rules at a step: an export applies them, then reports their shares
    // (count_fallback), and each asks for the same maps.
    struct RuleMemo {
        int frame = -1;
        int64_t step = -1;
        bool has_fallback = false, has_weight = false;
        torch::Tensor fallback, weight, gamma;
    };
    mutable RuleMemo m_rule_memo;
    mutable std::mutex m_rule_memo_mutex;
    torch::Tensor fallback_weight_now(int t) const;
    torch::Tensor model_weight_now(int t, torch::Tensor* gamma) const;
    mutable std::vector<torch::Tensor> m_seen;  // sharpest_seen_map's cache, under the mutex below
    mutable std::vector<torch::Tensor> m_seen_range;  // focus_range_map's, filled beside it
    mutable std::vector<FocusSpan> m_spans;  // each layer's focus_span (fg, bg), filled beside it
    mutable double m_resid_rms = 0;          // residual_rms()'s, at step m_resid_rms_step
    mutable int64_t m_resid_rms_step = -1;
    mutable std::mutex m_unexplained_mutex;
    int64_t m_pad = 0;     // training renders this margin beyond the frame (max_pad)
    bool m_crops = false;  // whether steps take crops (FitOptions::crop_px, and the model
                           // renders the blur's margin)
    std::mt19937_64 m_rng;
    std::vector<int64_t> m_perm;
    size_t m_perm_pos = 0;
    int m_batch = 2;  // frames per step: FitOptions::batch, or the model's choice
    int64_t m_step = 0;
    double m_elapsed = 0.0;
    double m_last_ckpt = 0.0;
    std::atomic<bool> m_stop{false}, m_paused{false};
    mutable std::mutex m_snap_mutex;
    mutable std::mutex m_model_mutex;
    FitSnapshot m_snap;
};

}  // namespace refocus
