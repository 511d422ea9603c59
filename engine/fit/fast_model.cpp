#include "fit/fast_model.h"
#include "util/activity.h"
#include "util/timing.h"

#include <torch/nn/functional.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "fit/flow_warp.h"
#include "model/atlas_geometry.h"
#include "fit/crops.h"
#include "fit/losses.h"
#include "ops/lens_blur.h"

#include <opencv2/video/tracking.hpp>
#include "util/debug.h"
#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

torch::Tensor upsample(const torch::Tensor& x, int64_t h, int64_t w, bool corners = false) {
    if (x.size(-2) == h && x.size(-1) == w) return x;
    return F::interpolate(x, F::InterpolateFuncOptions()
                                 .size(std::vector<int64_t>{h, w})
                                 .mode(torch::kBilinear)
                                 .align_corners(corners));
}

// Replicates the edge of [B,C,H,W] `pad` px outward.
torch::Tensor pad_edges(const torch::Tensor& x, int64_t pad) {
    if (pad == 0) return x;
    return F::pad(x, F::PadFuncOptions({pad, pad, pad, pad}).mode(torch::kReplicate));
}

torch::Tensor pixel_grid(int64_t H, int64_t W, int64_t pad) {
    auto ys = torch::arange(-pad, H + pad, torch::kFloat32),
         xs = torch::arange(-pad, W + pad, torch::kFloat32);
    auto grid = torch::meshgrid({ys, xs}, "ij");
    return torch::stack({grid[1].flatten(), grid[0].flatten(), torch::ones({grid[0].numel()})}, 1);
}

}  // namespace

FastModel::FastModel(const FitData& d, const FastModelOptions& opts) : m_data(d), m_opts(opts) {
    StageClock clock;  // --debug timing and the progress lines' activity
    clock.next("set-up: geometry and weights", "the atlases' geometry and the frames' weights");
    const int64_t T = d.frames, H = d.height, W = d.width;
    const int64_t P = opts.pad;
    m_pixels = pixel_grid(H, W, 0);
    m_pixels_pad = pixel_grid(H, W, P);
    const int64_t gh = H / opts.warp_cell_px + 2, gw = W / opts.warp_cell_px + 2;

    // Background atlas: the bounding box of every (padded) frame mapped into the reference frame.
    auto to_ref = d.to_ref.to(torch::kFloat64).contiguous();
    const AtlasBox box =
        mapped_frames_box(torch::matmul(to_ref, translation(-P, -P)), H + 2 * P, W + 2 * P);
    m_bg.origin_x = box.origin_x;
    m_bg.origin_y = box.origin_y;
    m_bg.width = box.width;
    m_bg.height = box.height;
    m_bg.to_atlas =
        torch::matmul(translation(-m_bg.origin_x, -m_bg.origin_y), to_ref).to(torch::kFloat32);
    m_bg.learn_warp = !d.static_camera;
    rescale(m_bg, opts.atlas_scale);
    m_bg.warp = torch::zeros({T, 2, gh, gw});

    torch::NoGradGuard no_grad;
    // The frames' fusion weights and regions are made frame by frame as a fusion or an
    // alignment reads them: as clip arrays they would be four full-size maps a frame written
    // through work/ (26 s at 1920x1080x240), for reads that cost less than the writing.
    const FrameFn sharpness = [&d](int64_t t) {
        return sharpness_weight(d.radius[t]).unsqueeze(0);
    };
    m_two_layers = d.has_subject && d.mask.defined();
    const bool two = m_two_layers;
    // Where each layer is seen: the mask's complement, or everywhere with one layer.
    const FrameFn bg_region = [&d, two](int64_t t) {
        return two ? 1.0 - d.mask[t] : torch::ones({1, d.height, d.width});
    };
    const FrameFn bg_weight = [&d, two, sharpness](int64_t t) {
        return two ? sharpness(t) * (1.0 - d.mask[t]).clamp_min(1e-3) : sharpness(t);
    };
    const FrameFn fg_weight = [&d, sharpness](int64_t t) {
        return sharpness(t) * d.mask[t].clamp_min(1e-3);
    };
    const FrameFn mask = [&d](int64_t t) { return d.mask[t]; };
    m_input_p = shrunk_once([&d](int64_t t) { return d.input[t]; });
    if (m_two_layers) {
        // Foreground mapping: translate so that each frame's subject centroid lands on one point.
        std::vector<double> vx, vy, sc;
        subject_track(d, vx, vy, &sc);
        const AtlasBox fbox = subject_box(d.mask, vx, vy, 12.0, &sc);
        m_fg.origin_x = fbox.origin_x;
        m_fg.origin_y = fbox.origin_y;
        m_fg.width = fbox.width;
        m_fg.height = fbox.height;
        std::vector<torch::Tensor> mats;
        for (int64_t t = 0; t < T; ++t)
            mats.push_back(sc[t] == 1.0
                               ? translation(-vx[t] - m_fg.origin_x, -vy[t] - m_fg.origin_y)
                               : torch::matmul(translation(-m_fg.origin_x, -m_fg.origin_y),
                                               subject_to_track(vx[t], vy[t], sc[t])));
        m_fg.to_atlas = torch::stack(mats).to(torch::kFloat32);
        m_fg.learn_warp = true;
        rescale(m_fg, opts.atlas_scale);
        m_fg.warp = torch::zeros({T, 2, gh, gw});
        // The subject's track may be off by a few px where the focus crosses it (its flow sees
        // the wall through its blurred edge); the reblurred sharpest views pull it back, which
        // takes corrections up to 10 px (docs/method.md, Model). A centroid track keeps 4 px.
        clock.next("set-up: align the subject", "aligning the subject's frames");
        const FrameFn fg_weight_p = shrunk_once(fg_weight);
        refine_alignment(m_fg, fg_weight, fg_weight_p, mask, d.legacy_subject_track ? 4.0 : 10.0);
        if (std::any_of(sc.begin(), sc.end(), [](double v) { return v != 1.0; })) {
            char line[200];
            std::snprintf(
                line, sizeof line,
                "fit (fast): the subject's size changes along the clip (%.2f-%.2f of its largest, "
                "from "
                "its flow): the atlas is prefiltered for each frame where the subject is smaller",
                *std::min_element(sc.begin(), sc.end()), *std::max_element(sc.begin(), sc.end()));
            notes.push_back(line);
        }
        clock.next("set-up: fuse the subject's atlas", "fusing the subject's atlas");
        init_levels(m_fg, m_opts.restore_only ? torch::zeros({3, m_fg.height, m_fg.width})
                                              : fuse_regions(m_fg, fg_weight, mask, fg_weight_p));
        clock.next("set-up: the matte", "fusing the matte");
        // Alpha (paper eq. 1): a matte shared by the frames, in the foreground atlas (half its
        // resolution), plus a per-frame residual (quarter resolution) for what moves on the
        // subject. The shared matte starts as the masks fused toward the frames that saw the
        // subject sharpest: a blurred subject's automatic mask loses its head and feet (synth
        // rack frames 0-15), a sharp one's does not.
        const double hs = 0.5;
        auto to_half =
            torch::tensor({hs, 0.0, 0.5 * hs - 0.5, 0.0, hs, 0.5 * hs - 0.5, 0.0, 0.0, 1.0},
                          torch::kFloat64)
                .view({3, 3});
        m_alpha_h = std::max<int64_t>(1, (m_fg.height + 1) / 2);
        m_alpha_w = std::max<int64_t>(1, (m_fg.width + 1) / 2);
        // How sharp the subject is in each frame is the subject's own radius (d.radius_fg where
        // the engine split it): where a blurred subject's mask lost its head, the visible
        // surface's radius there is the wall's, sharp when focus is on the wall, and such a
        // frame's "no head" would be trusted most.
        const auto subject_r = d.layer_radius(true).unsqueeze(1);
        auto fused_mask =
            m_opts.restore_only
                ? torch::full({1, m_alpha_h, m_alpha_w}, 0.5f)
                : fuse_frames(
                      torch::matmul(to_half, m_fg.to_atlas.to(torch::kFloat64)).to(torch::kFloat32),
                      m_alpha_h, m_alpha_w, [&](int64_t t) { return d.mask[t]; },
                      [&](int64_t t) { return sharpness_weight(subject_r[t]); });
        m_alpha_atlas = torch::logit(fused_mask.unsqueeze(0).clamp(0.01, 0.99));
        m_alpha_logit = torch::zeros({T, 1, (H + 3) / 4, (W + 3) / 4});
    }
    // A camera judged static (corners move < 2 px, prepare) maps every frame by the identity, as
    // its feature homographies are mostly noise (a focus change alone moves features). A
    // hand-held "static" shot still shakes by a pixel or so, which ECC against the reblurred
    // fused atlas finds; on a locked-off camera it finds ~0.
    if (!d.static_camera || m_opts.static_align) {
        const auto before = m_bg.to_atlas.clone();
        clock.next("set-up: align the background", "aligning the background's frames");
        // Corrections under 0.3 px are ECC's noise on a locked-off camera and are dropped: the
        // identity keeps its frames from flickering (docs/method.md, What is skipped when).
        auto still = [&] {
            return (m_bg.to_atlas - before)
                       .narrow(1, 0, 2)
                       .narrow(2, 2, 1)
                       .abs()
                       .max()
                       .item<double>() < 0.3 * m_bg.scale;
        };
        // On a long clip a camera judged static is first aligned on a sample of its frames, one
        // round: where none moves by 0.3 px the camera is locked off, and the rest would be too.
        constexpr int64_t kSample = 24;
        bool locked = false;
        if (d.static_camera && T > 2 * kSample && m_opts.align_rounds > 0) {
            std::vector<int64_t> sample;
            const int64_t stride = (T + kSample - 1) / kSample;
            for (int64_t t = stride / 2; t < T; t += stride) sample.push_back(t);
            refine_alignment(m_bg, bg_weight, {}, bg_region, 2.0, true, &sample, 1);
            locked = still();
            m_bg.to_atlas = before;
            if (locked)
                notes.push_back("fit (fast): static camera, locked off (no frame of " +
                                std::to_string(sample.size()) +
                                " sampled moves by 0.3 px): the background is not aligned");
        }
        if (!locked) {
            refine_alignment(m_bg, bg_weight, shrunk_once(bg_weight), bg_region,
                             d.static_camera ? 2.0 : m_opts.align_max_px, d.static_camera);
            if (d.static_camera && still()) m_bg.to_atlas = before;
        }
    }
    debug_memory("fast model: aligned");
    if (m_bg.learn_warp && m_opts.flow_warp && d.flow_fwd.defined() && T > 1) {
        const int64_t c = m_opts.flow_warp_cell_px;
        const auto fw = warps_from_flow(m_bg.to_atlas, m_bg.scale, d.flow_fwd, d.flow_valid,
                                        bg_region, H / c + 2, W / c + 2);
        m_bg.warp = fw.warp;
        char line[240];
        std::snprintf(line, sizeof line,
                      "fit (fast): background warps from the flow (%lld correspondences): frames "
                      "disagree by %.2f px through the homographies, %.2f px with the warps",
                      (long long)fw.points, fw.before_px, fw.after_px);
        notes.push_back(line);
    }
    if (m_bg.learn_warp && m_opts.parallax && T > 1) {
        // The flow on and near the subject is the subject's, not the wall's behind it: its mask
        // grown by 1/40 of the frame leaves it out. Restoring, the field is made (the checkpoint
        // names its tensors through state()) but not fitted to the flow.
        const int64_t g = std::max<int64_t>(1, std::min(H, W) / 40);
        std::function<torch::Tensor(int64_t)> region;
        if (!m_opts.restore_only)
            region = [&](int64_t t) {
                if (!m_two_layers) return bg_region(t);
                return 1.0 -
                       F::max_pool2d(d.mask[t].unsqueeze(0),
                                     F::MaxPool2dFuncOptions(2 * g + 1).stride(1).padding(g))[0];
            };
        const auto line = make_parallax(m_bg, region);
        if (!line.empty()) notes.push_back(line);
    }
    clock.next("set-up: fuse the background atlas", "fusing the background atlas");
    init_levels(m_bg, m_opts.restore_only
                          ? torch::zeros({3, m_bg.height, m_bg.width})
                          : fuse(
                                m_bg, bg_weight, [&](int64_t t) { return d.input[t]; }, true));
    debug_memory("fast model: background fused");
    clock.next("set-up: deblurring path", m_opts.deblur_path ? "the deblurring path" : "");
    if (m_opts.deblur_path) {
        auto line = make_deblur_path(m_bg, d.layer_radius(false), d.per_frame(bg_weight),
                                     d.per_frame(bg_region), "background");
        if (!line.empty()) notes.push_back(line);
        if (m_two_layers) {
            line = make_deblur_path(m_fg, d.layer_radius(true), d.per_frame(fg_weight), d.mask,
                                    "foreground");
            if (!line.empty()) notes.push_back(line);
        }
    }
    m_tv_stale = true;  // made by the first priors() (update_tv_weights)
    m_input_p = {};
    clock.end();
    set_activity("");
}

int FastModel::preferred_batch() const {
    return m_bg.deblur.defined() || m_fg.deblur.defined() ? m_opts.deblur_batch
                                                          : FitModel::preferred_batch();
}

std::string FastModel::preferred_batch_reason() const {
    return "a layer has the deblurring path; --batch 2 for the earlier default";
}

void FastModel::rescale(Atlas& a, double s) {
    // Frame pixel centre x ↦ atlas s·x + (s − 1)/2: atlas pixel j spans [j, j + 1) / s − ½.
    if (s == 1) return;
    a.width = int64_t(std::ceil(a.width * s));
    a.height = int64_t(std::ceil(a.height * s));
    auto S = torch::tensor({s, 0.0, 0.5 * (s - 1), 0.0, s, 0.5 * (s - 1), 0.0, 0.0, 1.0},
                           torch::kFloat64)
                 .view({3, 3});
    a.to_atlas = torch::matmul(S, a.to_atlas.to(torch::kFloat64)).to(torch::kFloat32);
    a.scale = s;
}

torch::Tensor FastModel::map_coords(const Atlas& a, const std::vector<int64_t>& frames,
                                    int64_t pad) const {
    const int64_t H = m_data.height, W = m_data.width, B = frames.size();
    if (pad != 0 && pad != m_opts.pad)
        throw Error("fast model: padding " + std::to_string(pad) + " px unsupported");
    const auto& pixels = pad ? m_pixels_pad : m_pixels;
    auto idx = torch::tensor(frames, torch::kLong);
    auto m = a.to_atlas.index_select(0, idx);         // [B,3,3]
    auto p = torch::matmul(m, pixels.t());            // [B,3,HW]
    auto xy = p.narrow(1, 0, 2) / p.narrow(1, 2, 1);  // [B,2,HW]
    auto px = xy.view({B, 2, H + 2 * pad, W + 2 * pad});
    if (a.learn_warp || a.warp.requires_grad())  // the residual warp is held constant past the edge
        px = px + a.scale * pad_edges(upsample(a.warp.index_select(0, idx), H, W, true), pad);
    return add_parallax(a, idx, px).permute({0, 2, 3, 1});  // [B,H,W,2]
}

torch::Tensor FastModel::to_grid(const Atlas& a, const torch::Tensor& px) const {
    // grid_sample with align_corners=false: pixel i has centre at (2i + 1)/size − 1.
    auto scale = torch::tensor({2.0f / a.width, 2.0f / a.height});
    return (px + 0.5) * scale - 1.0;
}

torch::Tensor FastModel::compose(const Atlas& a) const {
    torch::Tensor sum;
    for (const auto& l : a.levels) {
        auto up = upsample(l, a.height, a.width);
        sum = sum.defined() ? sum + up : up;
    }
    if (a.deblur.defined()) {
        const int64_t h = a.deblur_kernel.size(2) / 2;
        auto x = F::pad(a.deblur, F::PadFuncOptions({h, h, h, h}).mode(torch::kReplicate));
        sum = sum + upsample(F::conv2d(x, a.deblur_kernel, F::Conv2dFuncOptions().groups(3)),
                             a.height, a.width);
    }
    return sum;
}

torch::Tensor FastModel::fuse(const Atlas& a, const torch::Tensor& weight,
                              const torch::Tensor& what, bool with_warp) const {
    const torch::Tensor& src = what.defined() ? what : m_data.input;
    return fuse(
        a, [&](int64_t t) { return weight[t]; }, [&](int64_t t) { return src[t]; }, with_warp);
}

torch::Tensor FastModel::fuse(const Atlas& a, const FrameFn& weight, const FrameFn& src,
                              bool with_warp, const std::function<TexelBox(int64_t)>& window,
                              const torch::Tensor& fallback) const {
    // The margin starts as the frames' edges replicated outward, trusted 1000x less than what a
    // frame saw (a moving camera sees another frame's margin).
    const int64_t P = m_opts.pad;
    // The residual warps as map_coords adds them, when asked: only the first atlas is fused
    // through warps (from the flow); later fusions (TV weights, coverage) read the geometry,
    // which a resumed fit must find as the uninterrupted one did.
    std::function<torch::Tensor(int64_t)> offset;
    if (with_warp && a.parallax.defined())  // warps and parallax: the mapping less its homography
        offset = [&](int64_t t) {
            const int64_t H = m_data.height, W = m_data.width;
            const auto& pixels = P ? m_pixels_pad : m_pixels;
            auto p = torch::matmul(a.to_atlas[t], pixels.t());  // [3,N]
            auto base = (p.narrow(0, 0, 2) / p.narrow(0, 2, 1)).view({2, H + 2 * P, W + 2 * P});
            return map_coords(a, {t}, P)[0].permute({2, 0, 1}) - base;
        };
    else if (with_warp && a.warp.defined() && a.warp.abs().max().item<double>() > 0)
        offset = [&](int64_t t) {
            const int64_t H = m_data.height, W = m_data.width;
            return (a.scale * pad_edges(upsample(a.warp[t].unsqueeze(0), H, W, true), P))[0];
        };
    if (P == 0)
        return fuse_frames(a.to_atlas, a.height, a.width, src, weight, offset, window, fallback);
    auto inside = F::pad(torch::ones({1, 1, m_data.height, m_data.width}),
                         F::PadFuncOptions({P, P, P, P}).value(1e-3));
    auto shift = translation(-P, -P).to(a.to_atlas.dtype());
    // Frame by frame: the padded clip would be a clip-sized temporary.
    return fuse_frames(
        torch::matmul(a.to_atlas, shift), a.height, a.width,
        [&](int64_t t) { return pad_edges(src(t).unsqueeze(0), P)[0]; },
        [&](int64_t t) { return (pad_edges(weight(t).unsqueeze(0), P) * inside)[0]; }, offset,
        window, fallback);
}

void FastModel::init_levels(Atlas& a, const torch::Tensor& fused) {
    a.levels.clear();
    for (int l = 0; l < m_opts.levels; ++l) {
        const int shift = m_opts.levels - 1 - l;
        int64_t h = std::max<int64_t>(1, a.height >> shift),
                w = std::max<int64_t>(1, a.width >> shift);
        a.levels.push_back(torch::zeros({1, 3, h, w}));
    }
    a.levels.back() = fused.unsqueeze(0).clone();
    for (auto& l : a.levels) l.set_requires_grad(true);
    if (a.learn_warp) a.warp.set_requires_grad(true);
}

std::vector<ParamGroup> FastModel::param_groups() {
    std::vector<ParamGroup> g;
    ParamGroup atlas{{}, m_opts.lr_atlas};
    for (auto& l : m_bg.levels) atlas.params.push_back(l);
    if (m_two_layers)
        for (auto& l : m_fg.levels) atlas.params.push_back(l);
    g.push_back(atlas);
    ParamGroup deblur{{}, m_opts.lr_atlas * m_opts.deblur_lr};
    for (Atlas* a : {&m_bg, &m_fg})
        if (a->deblur.defined()) deblur.params.push_back(a->deblur);
    if (!deblur.params.empty()) g.push_back(deblur);
    ParamGroup warp{{}, m_opts.lr_warp};
    if (m_bg.learn_warp) warp.params.push_back(m_bg.warp);
    if (m_two_layers) warp.params.push_back(m_fg.warp);
    if (!warp.params.empty()) g.push_back(warp);
    if (m_bg.parallax.defined()) {
        g.push_back(ParamGroup{{m_bg.parallax.set_requires_grad(true)}, m_opts.lr_parallax});
        g.push_back(ParamGroup{{m_bg.epipole.set_requires_grad(true)}, m_opts.lr_epipole});
    }
    if (m_two_layers) {
        g.push_back(ParamGroup{{m_alpha_logit.set_requires_grad(true)}, m_opts.lr_alpha});
        g.push_back(ParamGroup{{m_alpha_atlas.set_requires_grad(true)},
                               m_opts.lr_alpha * m_opts.alpha_shared_lr});
    }
    return g;
}

Layers FastModel::render_padded(const std::vector<int64_t>& frames, int64_t pad) {
    const std::vector<int64_t> corner(frames.size(), -pad);
    return render_region(frames, corner, corner, m_data.height + 2 * pad, m_data.width + 2 * pad,
                         pad);
}

Layers FastModel::render_window(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                                const std::vector<int64_t>& y0, int64_t h, int64_t w) {
    check_windows("fast model", int64_t(frames.size()), m_data.height, m_data.width, m_opts.pad, x0,
                  y0, h, w);
    return render_region(frames, x0, y0, h, w, -1);
}

Layers FastModel::render_region(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                                const std::vector<int64_t>& y0, int64_t h, int64_t w, int64_t pad) {
    const int64_t B = frames.size(), H = m_data.height, W = m_data.width;
    Layers out;
    out.x0 = x0;
    out.y0 = y0;
    auto coords = [&](const Atlas& a) {
        return pad >= 0 ? map_coords(a, frames, pad) : map_coords_window(a, frames, x0, y0, h, w);
    };
    // The composed atlases (whole, or each window's part) are kept for priors() of the same
    // step: composing costs an upsample of each coarse level forward and backward.
    const bool training = torch::GradMode::is_enabled();
    const bool windows = pad < 0;  // and boxes, where they cost less than the atlas
    m_composed_bg = m_composed_fg = torch::Tensor();
    m_windows_bg.clear();
    m_windows_fg.clear();
    StageClock clock;  // --debug timing
    clock.next("render: the mappings");
    const auto px_bg = coords(m_bg);
    out.uv_bg = to_grid(m_bg, px_bg);
    auto wins = windows ? paying_windows(m_bg, px_bg, frames, false) : std::vector<AtlasWindow>{};
    if (!wins.empty()) {
        out.bg = sample_windows(m_bg, px_bg, std::move(wins), training ? &m_windows_bg : nullptr);
    } else {
        clock.next("render: compose the atlases");
        auto bg = training ? compose(m_bg) : compose_still(m_bg, m_still_bg);
        m_composed_bg = training ? bg : torch::Tensor();
        clock.next("render: sample the atlases");
        out.bg = sample_bicubic(bg.expand({B, 3, m_bg.height, m_bg.width}), out.uv_bg);
    }
    if (!m_two_layers) {
        out.sharp = out.bg;
        return out;
    }
    clock.next("render: the mappings");
    const auto px_fg = coords(m_fg);
    out.uv_fg = to_grid(m_fg, px_fg);
    wins = windows ? paying_windows(m_fg, px_fg, frames, true) : std::vector<AtlasWindow>{};
    if (!wins.empty()) {
        out.fg = sample_windows(m_fg, px_fg, std::move(wins), training ? &m_windows_fg : nullptr);
    } else {
        clock.next("render: compose the atlases");
        auto fg = training ? compose(m_fg) : compose_still(m_fg, m_still_fg);
        m_composed_fg = training ? fg : torch::Tensor();
        clock.next("render: prefilter the subject");
        auto small = minified(fg, frames);
        clock.next("render: sample the atlases");
        out.fg = sample_bicubic(small, out.uv_fg);
    }
    clock.next("render: the matte");
    auto idx = torch::tensor(frames, torch::kLong);
    // The shared matte through the foreground mapping (its grid [-1,1] spans the atlas, which
    // the half-resolution matte spans too) plus the frame's residual.
    auto shared = F::grid_sample(m_alpha_atlas.expand({B, 1, m_alpha_h, m_alpha_w}), out.uv_fg,
                                 F::GridSampleFuncOptions()
                                     .mode(torch::kBilinear)
                                     .padding_mode(torch::kBorder)
                                     .align_corners(false));
    auto residual = m_alpha_logit.index_select(0, idx);
    residual = pad >= 0 ? pad_edges(upsample(residual, H, W), pad)
                        : upsample_window(residual, H, W, x0, y0, h, w, false);
    out.alpha = torch::sigmoid(shared + residual);
    out.sharp = out.alpha * out.fg + (1.0 - out.alpha) * out.bg;  // paper eq. 1
    return out;
}

torch::Tensor FastModel::priors(const Layers& layers, const std::vector<int64_t>& frames,
                                int64_t step, LossTerms& terms) {
    if (m_tv_stale) {
        update_tv_weights();
        m_tv_stale = false;
    }
    // A layer with a deblurring path takes deblur_tv times the TV: its detail is what TV flattens.
    auto tv_factor = [&](const Atlas& a) { return a.deblur.defined() ? m_opts.deblur_tv : 1.0; };
    // Over windows (the crop step), each prior covers what the windows read only.
    const bool whole = covers_frames(layers);
    auto atlas_tv = [&](const Atlas& a, const torch::Tensor& composed,
                        const std::vector<AtlasWindow>& wins, const torch::Tensor& uv) {
        if (!whole) return window_tv(a, wins, composed, uv);
        return tv_l1(composed.defined() ? composed : compose(a), a.tv_weight);
    };
    auto tv = tv_factor(m_bg) * atlas_tv(m_bg, m_composed_bg, m_windows_bg, layers.uv_bg);
    if (m_two_layers)
        tv = tv + tv_factor(m_fg) * atlas_tv(m_fg, m_composed_fg, m_windows_fg, layers.uv_fg);
    m_composed_bg = m_composed_fg = torch::Tensor();
    m_windows_bg.clear();
    m_windows_fg.clear();
    // TV in frame px: a 2x atlas's neighbours differ by half as much, so the weight scales with
    // the atlas (docs/method.md, Model).
    torch::Tensor total = m_opts.w_tv * m_bg.scale * tv;
    terms["tv"] = tv.item<double>();
    auto idx = torch::tensor(frames, torch::kLong);
    torch::Tensor warp_reg = torch::zeros({});
    for (Atlas* a : {&m_bg, &m_fg}) {
        if (!a->warp.requires_grad()) continue;
        if (!whole) {
            warp_reg = warp_reg + window_warp(*a, layers, frames);
            continue;
        }
        auto w = a->warp.index_select(0, idx);
        warp_reg = warp_reg + warp_smoothness(w);
    }
    total = total + m_opts.w_warp * warp_reg;
    terms["warp"] = warp_reg.item<double>();
    if (m_bg.parallax.defined()) {
        auto reg = parallax_smoothness(m_bg.parallax);
        total = total + m_opts.w_parallax * reg;
        terms["parallax"] = reg.item<double>();
    }
    // Temporal smoothness of the per-frame residuals (off by default: FastModelOptions::w_temporal
    // says why; the shared atlases already keep the frames consistent).
    const int64_t T = m_data.frames;
    if (T > 1 && m_opts.w_temporal > 0) {
        std::vector<int64_t> nb;
        for (int64_t f : frames) nb.push_back(f + 1 < T ? f + 1 : f - 1);
        auto nidx = torch::tensor(nb, torch::kLong);
        torch::Tensor temporal = torch::zeros({});
        for (Atlas* a : {&m_bg, &m_fg})
            if (a->warp.requires_grad())
                temporal =
                    temporal +
                    (a->warp.index_select(0, idx) - a->warp.index_select(0, nidx)).pow(2).mean();
        if (m_two_layers)
            temporal = temporal + 0.25 * (m_alpha_logit.index_select(0, idx) -
                                          m_alpha_logit.index_select(0, nidx))
                                             .abs()
                                             .mean();
        total = total + m_opts.w_temporal * temporal;
        terms["temporal"] = temporal.item<double>();
    }
    if (m_two_layers) {
        // Mask bootstrap (Layered Neural Atlases §3.3): pull α toward the masks early, then let
        // the reconstruction decide the soft edge.
        const double decay = std::pow(0.5, double(step) / m_opts.bootstrap_halflife);
        auto boot = bootstrap_l1(layers, frames);
        total = total + m_opts.w_bootstrap * decay * boot;
        terms["bootstrap"] = boot.item<double>();
        // The residual stays small: what the frames share lives in the shared matte.
        auto res = whole ? m_alpha_logit.index_select(0, idx).abs().mean()
                         : window_alpha_residual(layers, frames);
        total = total + m_opts.w_alpha_residual * res;
        terms["alpha_residual"] = res.item<double>();
    }
    return total;
}

torch::Tensor FastModel::atlas_bg() {
    return compose(m_bg).detach()[0];
}
torch::Tensor FastModel::atlas_fg() {
    return m_two_layers ? compose(m_fg).detach()[0] : torch::Tensor();
}

void FastModel::set_atlas(Atlas& a, const torch::Tensor& rgb) {
    if (rgb.dim() != 3 || rgb.size(0) != 3 || rgb.size(1) != a.height || rgb.size(2) != a.width)
        throw Error("atlas image must be 3x" + std::to_string(a.height) + "x" +
                    std::to_string(a.width) + " (channels x height x width)");
    torch::NoGradGuard g;
    torch::Tensor coarse = torch::zeros({1, 3, a.height, a.width});
    for (size_t l = 0; l + 1 < a.levels.size(); ++l)
        coarse += upsample(a.levels[l], a.height, a.width);
    if (a.deblur.defined()) a.deblur.zero_();  // the image is the atlas: the texels hold all of it
    a.levels.back().copy_(rgb.unsqueeze(0) - coarse);
}
void FastModel::set_atlas_bg(const torch::Tensor& rgb) {
    set_atlas(m_bg, rgb);
}
void FastModel::set_atlas_fg(const torch::Tensor& rgb) {
    if (!m_two_layers) throw Error("this fit has one layer: there is no foreground atlas");
    set_atlas(m_fg, rgb);
}

void FastModel::load_state(const std::map<std::string, torch::Tensor>& in) {
    auto s = in;
    // A checkpoint without "alpha_atlas" held all of alpha in its per-frame matte.
    if (m_two_layers && !s.count("alpha_atlas"))
        s["alpha_atlas"] = torch::zeros_like(m_alpha_atlas);
    adopt_geometry(m_bg, "bg", s);
    if (m_two_layers) {
        adopt_geometry(m_fg, "fg", s);
        const auto& a = s.at("alpha_atlas");
        if (a.dim() == 4 && !a.sizes().equals(m_alpha_atlas.sizes())) {
            m_alpha_atlas = torch::zeros_like(a);
            m_alpha_h = a.size(2);
            m_alpha_w = a.size(3);
        }
    }
    FitModel::load_state(s);  // the parameters may be new tensors: the engine remakes its optimiser
    m_tv_stale = true;        // over the adopted geometry, at the next priors()
}

torch::Tensor FastModel::geometry(const Atlas& a) {
    return torch::tensor({a.origin_x, a.origin_y, double(a.width), double(a.height)},
                         torch::kFloat64);
}

void FastModel::adopt_geometry(Atlas& a, const std::string& name,
                               std::map<std::string, torch::Tensor>& s) {
    auto g = s.find(name + "_geometry"), m = s.find(name + "_to_atlas");
    if (g == s.end() || m == s.end()) {  // a checkpoint without it: the computed geometry
        s[name + "_geometry"] = geometry(a);
        s[name + "_to_atlas"] = a.to_atlas;
        return;
    }
    if (!g->second.sizes().equals({4}) || !m->second.sizes().equals(a.to_atlas.sizes()))
        throw Error("checkpoint geometry of the " + name + " atlas has shape " +
                    c10::str(g->second.sizes()) + " / " + c10::str(m->second.sizes()) +
                    ", the model expects [4] / " + c10::str(a.to_atlas.sizes()));
    auto v = g->second.to(torch::kFloat64).contiguous();
    const double* p = v.data_ptr<double>();
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !(p[2] >= 1 && p[2] < 1e5) ||
        !(p[3] >= 1 && p[3] < 1e5) || !torch::isfinite(m->second).all().item<bool>())
        throw Error("checkpoint geometry of the " + name + " atlas is not finite or out of range");
    a.origin_x = p[0];
    a.origin_y = p[1];
    a.width = int64_t(p[2]);
    a.height = int64_t(p[3]);
    a.to_atlas = m->second.to(torch::kFloat32).clone();
    for (size_t l = 0; l < a.levels.size(); ++l) {
        auto it = s.find(name + "_level" + std::to_string(l));
        if (it != s.end() && !it->second.sizes().equals(a.levels[l].sizes()))
            a.levels[l] = torch::zeros_like(it->second);  // copied into by FitModel::load_state
    }
    {  // the residual warps' grid is the checkpoint's (fast.flow_warp_cell_px may differ)
        auto it = s.find(name + "_warp");
        if (it != s.end() && it->second.dim() == 4 && it->second.size(0) == a.warp.size(0) &&
            it->second.size(1) == 2 && !it->second.sizes().equals(a.warp.sizes()))
            a.warp = torch::zeros_like(it->second).set_requires_grad(a.warp.requires_grad());
    }
    {  // plane + parallax: the checkpoint's, whether or not this build's settings would make it
        auto g = s.find(name + "_parallax"), e = s.find(name + "_epipole"),
             c = s.find(name + "_parallax_centre");
        if (g != s.end() && e != s.end() && c != s.end()) {
            if (g->second.dim() != 4 || g->second.size(0) != 1 || g->second.size(1) != 1 ||
                !e->second.sizes().equals({a.to_atlas.size(0), 3}) ||
                !c->second.sizes().equals({a.to_atlas.size(0), 2}))
                throw Error("checkpoint parallax of the " + name + " atlas has shape " +
                            c10::str(g->second.sizes()) + " / " + c10::str(e->second.sizes()));
            const bool learn = a.parallax.defined() && a.parallax.requires_grad();
            a.parallax = torch::zeros_like(g->second).set_requires_grad(learn);
            a.epipole = torch::zeros_like(e->second).set_requires_grad(learn);
            a.centre = torch::zeros_like(c->second);
            a.parallax_radius =
                0.5 *
                std::sqrt(double(m_data.width * m_data.width + m_data.height * m_data.height)) *
                a.scale;
        } else if (a.parallax.defined() && m_opts.restore_only) {  // the fit kept no field
            a.parallax = torch::Tensor();
            a.epipole = torch::Tensor();
            a.centre = torch::Tensor();
        } else if (a.parallax.defined()) {  // fitted without: γ = 0 renders as it did
            s[name + "_parallax"] = torch::zeros_like(a.parallax);
            s[name + "_epipole"] = a.epipole.detach().clone();
            s[name + "_parallax_centre"] = a.centre;
        }
    }
    if (a.deblur.defined()) {
        auto it = s.find(name + "_deblur");
        if (it == s.end())  // a checkpoint without the path: its texels hold the whole atlas
            s[name + "_deblur"] = torch::zeros_like(a.deblur);
        else if (!it->second.sizes().equals(a.deblur.sizes()))
            a.deblur = torch::zeros_like(it->second);
    }
}

std::map<std::string, torch::Tensor> FastModel::state() {
    std::map<std::string, torch::Tensor> s;
    for (size_t l = 0; l < m_bg.levels.size(); ++l)
        s["bg_level" + std::to_string(l)] = m_bg.levels[l];
    s["bg_warp"] = m_bg.warp;
    if (m_bg.deblur.defined()) s["bg_deblur"] = m_bg.deblur;
    if (m_bg.parallax.defined()) {
        s["bg_parallax"] = m_bg.parallax;
        s["bg_epipole"] = m_bg.epipole;
        s["bg_parallax_centre"] = m_bg.centre;
    }
    s["bg_geometry"] = geometry(m_bg);
    s["bg_to_atlas"] = m_bg.to_atlas;
    if (m_two_layers) {
        s["fg_geometry"] = geometry(m_fg);
        s["fg_to_atlas"] = m_fg.to_atlas;
        for (size_t l = 0; l < m_fg.levels.size(); ++l)
            s["fg_level" + std::to_string(l)] = m_fg.levels[l];
        s["fg_warp"] = m_fg.warp;
        if (m_fg.deblur.defined()) s["fg_deblur"] = m_fg.deblur;
        s["alpha_logit"] = m_alpha_logit;
        s["alpha_atlas"] = m_alpha_atlas;
    }
    return s;
}

}  // namespace refocus
