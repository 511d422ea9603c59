#include "fit/paper_model.h"

#include "model/atlas_geometry.h"

#include <torch/nn/functional.h>
#include <torch/optim.h>
#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <random>

#include "util/debug.h"
#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

int64_t round_up8(int64_t v) {
    return (v + 7) / 8 * 8;
}

// Rigidity of a 2×2 Jacobian field (Layered Neural Atlases §3.3, their code): J is a rotation
// iff JᵀJ = I; ‖JᵀJ‖_F + ‖(JᵀJ)⁻¹‖_F − 2√2 is 0 there and grows with stretch and shrink alike.
// Clamped per point: a mapping that has saturated (tanh) outside its atlas should not dominate.
// J: [N,2,2] → [N].
torch::Tensor rigidity_of(const torch::Tensor& J) {
    auto jtj = torch::matmul(J.transpose(1, 2), J);
    auto a = jtj.select(1, 0).select(1, 0) + 1e-3, b = jtj.select(1, 0).select(1, 1);
    auto c = jtj.select(1, 1).select(1, 0), d = jtj.select(1, 1).select(1, 1) + 1e-3;
    auto det = a * d - b * c;
    auto fw = (a.pow(2) + b.pow(2) + c.pow(2) + d.pow(2)).sqrt();
    auto bw = (a.pow(2) + b.pow(2) + c.pow(2) + d.pow(2)).sqrt() / det;  // ‖M⁻¹‖_F = ‖M‖_F/|det|
    return (fw + bw - 2.0 * std::sqrt(2.0)).clamp(0.0, 10.0);
}

}  // namespace

// ------------------------------------------------------------------------------- networks

CoordMlpImpl::CoordMlpImpl(int freqs_, int layers, int width, int out) : freqs(freqs_) {
    net = torch::nn::Sequential();
    int in = 3 + 3 * 2 * freqs;
    for (int l = 0; l < layers - 1; ++l) {
        net->push_back(torch::nn::Linear(in, width));
        net->push_back(torch::nn::ReLU());
        in = width;
    }
    net->push_back(torch::nn::Linear(in, out));
    register_module("net", net);
}

torch::Tensor CoordMlpImpl::forward(const torch::Tensor& p) {
    // Positional encoding γ(p) = (p, sin 2^k π p, cos 2^k π p), k < freqs (LNA, NeRF).
    std::vector<torch::Tensor> enc{p};
    for (int k = 0; k < freqs; ++k) {
        auto s = p * (std::pow(2.0, k) * M_PI);
        enc.push_back(torch::sin(s));
        enc.push_back(torch::cos(s));
    }
    return net->forward(torch::cat(enc, -1));
}

AtlasDecoderImpl::AtlasDecoderImpl(int in_channels, const std::vector<int>& channels) {
    net = torch::nn::Sequential();
    int in = in_channels;
    for (int c : channels) {  // paper §3.2: upsampling by pixel shuffle (Shi et al. 2016)
        net->push_back(torch::nn::Conv2d(torch::nn::Conv2dOptions(in, 4 * c, 3).padding(1)));
        // Leaky ReLU (0.2) as in Deep Image Prior: plain ReLU units die when the decoder is
        // pre-trained at a useful learning rate, and the atlas collapses to black.
        net->push_back(torch::nn::LeakyReLU(torch::nn::LeakyReLUOptions().negative_slope(0.2)));
        net->push_back(torch::nn::PixelShuffle(2));
        in = c;
    }
    net->push_back(torch::nn::Conv2d(torch::nn::Conv2dOptions(in, 3, 3).padding(1)));
    net->push_back(torch::nn::Sigmoid());
    register_module("net", net);
}

torch::Tensor AtlasDecoderImpl::forward(const torch::Tensor& z) {
    return net->forward(z);
}

// ------------------------------------------------------------------------------- model

PaperModel::PaperModel(const FitData& d, const PaperModelOptions& options, uint64_t seed)
    : m_data(d), m_opts(options), m_seed(seed) {
    const PaperModelOptions& opts = m_opts;
    if (opts.decoder_channels.size() != 3)
        throw Error(
            "paper preset: the atlas decoder has 3 pixel-shuffle stages (atlas = 8 × noise)");
    torch::manual_seed(seed);
    const int64_t T = d.frames, H = d.height, W = d.width;
    const int s = std::max(1, opts.mlp_stride);
    m_lh = std::max<int64_t>(1, (H + s - 1) / s);
    m_lw = std::max<int64_t>(1, (W + s - 1) / s);
    m_two_layers = d.has_subject && d.mask.defined();

    // Background atlas: the bounding box of every frame mapped into the reference frame (as the
    // fast preset), rounded up to a multiple of 8 for the decoder.
    auto to_ref = d.to_ref.to(torch::kFloat64).contiguous();
    const AtlasBox box = mapped_frames_box(to_ref, H, W);
    const double ox = box.origin_x, oy = box.origin_y;
    m_bg.width = round_up8(box.width);
    m_bg.height = round_up8(box.height);
    m_bg.to_atlas = torch::matmul(translation(-ox, -oy), to_ref).to(torch::kFloat32);
    m_bg.map = CoordMlp(opts.map_freqs, opts.map_layers, opts.map_width, 2);
    init_residual(m_bg);
    // A static camera gets the exact identity mapping (as the fast preset: docs/method.md, What
    // is skipped when): a learned residual there only drifts, fitting the reblur rather than the
    // scene, so the sharp output falls and flickers as the reblur improves (docs/method.md,
    // Presets).
    m_bg.learn_residual = !d.static_camera;

    torch::NoGradGuard no_grad;
    auto ys = torch::arange(H, torch::kFloat32), xs = torch::arange(W, torch::kFloat32);
    auto grid = torch::meshgrid({ys, xs}, "ij");
    const auto sharpness = sharpness_weight(d.radius).unsqueeze(1);  // [T,1,H,W]
    torch::Tensor bg_weight = sharpness, fg_weight;
    if (m_two_layers) {
        bg_weight = sharpness * (1.0 - d.mask).clamp_min(1e-3);
        fg_weight = sharpness * d.mask.clamp_min(1e-3);
        // Foreground: translate each frame's point of the subject's track onto one point — the
        // fast preset's stabilised mapping, here the pre-training target of M_f.
        std::vector<double> sx, sy;
        subject_track(d, sx, sy);
        const AtlasBox fbox = subject_box(d.mask, sx, sy, 12.0);
        const double fox = fbox.origin_x, foy = fbox.origin_y;
        // No larger than the background atlas (the frame's bounding box): masks that flag stray
        // edges far from the subject can make the stabilised box up to 3× the frame, an atlas
        // the decoder would spend most of its time on.
        m_fg.width = round_up8(std::min<int64_t>(fbox.width, m_bg.width));
        m_fg.height = round_up8(std::min<int64_t>(fbox.height, m_bg.height));
        std::vector<torch::Tensor> mats;
        for (int64_t t = 0; t < T; ++t) mats.push_back(translation(-sx[t] - fox, -sy[t] - foy));
        m_fg.to_atlas = torch::stack(mats).to(torch::kFloat32);
        m_fg.map = CoordMlp(opts.map_freqs, opts.map_layers, opts.map_width, 2);
        init_residual(m_fg);
        m_alpha = CoordMlp(opts.alpha_freqs, opts.alpha_layers, opts.alpha_width, 1);
    }
    m_decoder = AtlasDecoder(opts.noise_channels, opts.decoder_channels);
    // Z_b, Z_f: fixed, seeded noise (Deep Image Prior, Ulyanov et al. 2018). Unit Gaussian, not
    // DIP's uniform ×0.1: without DIP's batch norm a faint input leaves the biases in charge and
    // the pre-training collapses the atlas to a saturated constant.
    m_bg.noise = torch::randn({1, opts.noise_channels, m_bg.height / 8, m_bg.width / 8});
    if (m_two_layers)
        m_fg.noise = torch::randn({1, opts.noise_channels, m_fg.height / 8, m_fg.width / 8});

    auto fb = fused(m_bg, bg_weight, d.input);
    torch::Tensor ff;
    if (m_two_layers) {
        // The foreground atlas starts black where no frame sees the subject: what the sparsity
        // prior asks for (paper §3.5), so that it does not fight the start.
        auto cover = fused(m_fg, fg_weight, d.mask).clamp(0, 1);
        ff = fused(m_fg, fg_weight, d.input) * cover;
    }
    {
        torch::AutoGradMode grad(true);
        const auto t0 = std::chrono::steady_clock::now();
        pretrain_mappings();
        const auto t1 = std::chrono::steady_clock::now();
        pretrain_atlases(fb, ff);
        if (debug_enabled("paper"))
            std::fprintf(
                stderr,
                "paper: atlas bg %lldx%lld fg %lldx%lld; pretrain maps %.1f s, atlases %.1f s\n",
                (long long)m_bg.width, (long long)m_bg.height, (long long)m_fg.width,
                (long long)m_fg.height, std::chrono::duration<double>(t1 - t0).count(),
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count());
    }
}

void PaperModel::init_residual(Layer& l) {
    // The last layer starts at zero: M(p) is the geometric mapping exactly at step 0.
    torch::NoGradGuard g;
    auto last = l.map->net->ptr(l.map->net->size() - 1)->as<torch::nn::Linear>();
    last->weight.zero_();
    last->bias.zero_();
    l.residual_scale = torch::tensor(
        {float(m_opts.residual_px * 2.0 / l.width), float(m_opts.residual_px * 2.0 / l.height)});
}

torch::Tensor PaperModel::coords(const torch::Tensor& x, const torch::Tensor& y,
                                 const torch::Tensor& t) const {
    // p = (x, y, t) → [−1, 1]: pixel centres 0 … W−1, frames 0 … T−1.
    const double W = m_data.width, H = m_data.height, T = m_data.frames;
    auto xn = W > 1 ? x * (2.0 / (W - 1)) - 1.0 : x * 0.0;
    auto yn = H > 1 ? y * (2.0 / (H - 1)) - 1.0 : y * 0.0;
    auto tn = T > 1 ? t * (2.0 / (T - 1)) - 1.0 : t * 0.0;
    return torch::stack({xn, yn, tn}, -1);
}

torch::Tensor PaperModel::lattice(const std::vector<int64_t>& frames) const {
    // Lattice pixel j sits at fine pixel (j + ½)·W/w − ½: the centres F::interpolate
    // (bilinear, align_corners = false) assumes when it brings the lattice back to W.
    const int64_t B = frames.size();
    auto ly = (torch::arange(m_lh, torch::kFloat32) + 0.5) * (double(m_data.height) / m_lh) - 0.5;
    auto lx = (torch::arange(m_lw, torch::kFloat32) + 0.5) * (double(m_data.width) / m_lw) - 0.5;
    auto g = torch::meshgrid({ly, lx}, "ij");
    auto t = torch::tensor(frames, torch::kFloat32).view({B, 1, 1}).expand({B, m_lh, m_lw});
    return coords(g[1].expand({B, m_lh, m_lw}), g[0].expand({B, m_lh, m_lw}), t);
}

torch::Tensor PaperModel::full_lattice(const std::vector<int64_t>& frames) const {
    const int64_t B = frames.size(), H = m_data.height, W = m_data.width;
    auto g = torch::meshgrid({torch::arange(H, torch::kFloat32), torch::arange(W, torch::kFloat32)},
                             "ij");
    auto t = torch::tensor(frames, torch::kFloat32).view({B, 1, 1}).expand({B, H, W});
    return coords(g[1].expand({B, H, W}), g[0].expand({B, H, W}), t);
}

torch::Tensor PaperModel::target_uv(const Layer& l, const torch::Tensor& px,
                                    const torch::Tensor& t) const {
    // px [N,2] frame pixels, t [N] long → [N,2] grid coordinates of the homography mapping.
    auto m = l.to_atlas.index_select(0, t);                                   // [N,3,3]
    auto h = torch::cat({px, torch::ones({px.size(0), 1})}, 1).unsqueeze(2);  // [N,3,1]
    auto q = torch::matmul(m, h).squeeze(2);
    auto a = q.narrow(1, 0, 2) / q.narrow(1, 2, 1);
    auto scale = torch::tensor({2.0f / l.width, 2.0f / l.height});
    return (a + 0.5) * scale - 1.0;
}

torch::Tensor PaperModel::residual(Layer& l, const torch::Tensor& p) {
    auto shape = p.sizes().vec();
    shape.back() = 2;
    if (!l.learn_residual) return torch::zeros(shape);
    return (torch::tanh(l.map->forward(p.reshape({-1, 3}))) * l.residual_scale).view(shape);
}

torch::Tensor PaperModel::base_uv(const Layer& l, const torch::Tensor& p) const {
    // p normalised → frame pixel and frame index → the geometric mapping's grid coordinates.
    const double W = m_data.width, H = m_data.height, T = m_data.frames;
    auto q = p.reshape({-1, 3});
    auto px = torch::stack(
        {(q.select(1, 0) + 1.0) * ((W - 1) / 2.0), (q.select(1, 1) + 1.0) * ((H - 1) / 2.0)}, 1);
    auto t = ((q.select(1, 2) + 1.0) * ((T - 1) / 2.0)).round().clamp(0, T - 1).to(torch::kLong);
    auto shape = p.sizes().vec();
    shape.back() = 2;
    return target_uv(l, px, t).view(shape);
}

torch::Tensor PaperModel::uv(Layer& l, const torch::Tensor& p) {
    return base_uv(l, p) + residual(l, p);
}

torch::Tensor PaperModel::alpha(const torch::Tensor& p) {
    auto shape = p.sizes().vec();
    shape.back() = 1;
    return torch::sigmoid(m_alpha->forward(p.reshape({-1, 3}))).view(shape);
}

torch::Tensor PaperModel::up(const torch::Tensor& x) const {
    if (x.size(-2) == m_data.height && x.size(-1) == m_data.width) return x;
    return F::interpolate(x, F::InterpolateFuncOptions()
                                 .size(std::vector<int64_t>{m_data.height, m_data.width})
                                 .mode(torch::kBilinear)
                                 .align_corners(false));
}

torch::Tensor PaperModel::fused(const Layer& l, const torch::Tensor& weight,
                                const torch::Tensor& src) const {
    // The fast preset's starting atlas (atlas_geometry.h).
    return fuse_frames(l.to_atlas, l.height, l.width, src, weight).clamp(0, 1);
}

torch::Tensor PaperModel::sample_points(int64_t n, uint64_t salt, bool flow_frames) const {
    // Deterministic in (seed, salt) so that a resumed fit draws the same points as an
    // uninterrupted one (the global torch generator is not checkpointed).
    std::mt19937_64 rng(m_seed * 0x9E3779B97F4A7C15ULL + salt);
    const int64_t tmax = flow_frames ? m_data.frames - 1 : m_data.frames;
    std::uniform_int_distribution<int64_t> dt(0, std::max<int64_t>(0, tmax - 1));
    std::uniform_int_distribution<int64_t> dx(0, m_data.width - 1), dy(0, m_data.height - 1);
    std::vector<float> v(3 * n);
    for (int64_t i = 0; i < n; ++i) {
        v[3 * i] = float(dx(rng));
        v[3 * i + 1] = float(dy(rng));
        v[3 * i + 2] = float(dt(rng));
    }
    return torch::from_blob(v.data(), {n, 3}, torch::kFloat32).clone();
}

void PaperModel::pretrain_mappings() {
    // M_b, M_f start as the geometric mapping exactly (zero residual, see the header); M_α is
    // pre-trained to the masks (LNA's bootstrap).
    if (!m_two_layers) return;
    torch::optim::Adam opt(m_alpha->parameters(), torch::optim::AdamOptions(1e-3));
    const int64_t n = 2048;
    for (int it = 0; it < m_opts.pretrain_map_steps; ++it) {
        auto pts = sample_points(n, 1000000 + it, false);
        auto tf = pts.select(1, 2);
        auto t = tf.to(torch::kLong);
        auto p = coords(pts.select(1, 0), pts.select(1, 1), tf);
        auto lin = t * (m_data.height * m_data.width) +
                   pts.select(1, 1).to(torch::kLong) * m_data.width +
                   pts.select(1, 0).to(torch::kLong);
        auto mk = m_data.mask.reshape({-1}).index_select(0, lin).unsqueeze(1);
        auto loss = 10.0 * (alpha(p) - mk).pow(2).mean();
        opt.zero_grad();
        loss.backward();
        opt.step();
        if (debug_enabled("paper") && it + 1 == m_opts.pretrain_map_steps)
            std::fprintf(stderr, "paper: alpha pre-training loss %.4g\n", loss.item<double>());
    }
}

void PaperModel::pretrain_atlases(const torch::Tensor& fused_bg, const torch::Tensor& fused_fg) {
    if (m_opts.pretrain_atlas_steps <= 0) return;
    torch::optim::Adam opt(m_decoder->parameters(),
                           torch::optim::AdamOptions(m_opts.lr_pretrain_atlas));
    for (int it = 0; it < m_opts.pretrain_atlas_steps; ++it) {
        auto loss = (m_decoder->forward(m_bg.noise)[0] - fused_bg).abs().mean();
        if (m_two_layers) loss = loss + (m_decoder->forward(m_fg.noise)[0] - fused_fg).abs().mean();
        opt.zero_grad();
        loss.backward();
        opt.step();
        if (debug_enabled("paper") && it + 1 == m_opts.pretrain_atlas_steps)
            std::fprintf(stderr, "paper: atlas pre-training L1 %.4g\n", loss.item<double>());
        if (debug_enabled("paper") && it % 50 == 0)
            std::fprintf(
                stderr,
                "paper: atlas pre-training step %d L1 %.4g target bg mean %.3g fg mean %.3g\n", it,
                loss.item<double>(), fused_bg.mean().item<double>(),
                fused_fg.defined() ? fused_fg.mean().item<double>() : 0.0);
    }
}

std::vector<ParamGroup> PaperModel::param_groups() {
    std::vector<ParamGroup> g;
    g.push_back(ParamGroup{m_decoder->parameters(), m_opts.lr_decoder});
    ParamGroup maps{{}, m_opts.lr_map};
    if (m_bg.learn_residual) maps.params = m_bg.map->parameters();
    if (m_two_layers)
        for (auto& p : m_fg.map->parameters()) maps.params.push_back(p);
    if (!maps.params.empty()) g.push_back(maps);
    if (m_two_layers) g.push_back(ParamGroup{m_alpha->parameters(), m_opts.lr_alpha});
    return g;
}

Layers PaperModel::render(const std::vector<int64_t>& frames) {
    const int64_t B = frames.size();
    Layers out;
    auto p = lattice(frames);                       // [B,h,w,3]
    auto to_full = [&](const torch::Tensor& lat) {  // [B,h,w,C] → [B,H,W,C]
        return up(lat.permute({0, 3, 1, 2})).permute({0, 2, 3, 1}).contiguous();
    };
    auto full = full_lattice(frames);  // [B,H,W,3]
    out.uv_bg = base_uv(m_bg, full) + to_full(residual(m_bg, p));
    auto ab = m_decoder->forward(m_bg.noise);  // A_b = 𝔸(Z_b)   [1,3,Ha,Wa]
    out.bg = sample_bicubic(ab.expand({B, 3, m_bg.height, m_bg.width}), out.uv_bg);
    if (!m_two_layers) {
        out.sharp = out.bg;
        return out;
    }
    out.uv_fg = base_uv(m_fg, full) + to_full(residual(m_fg, p));
    auto af = m_decoder->forward(m_fg.noise);  // A_f = 𝔸(Z_f), shared weights (§3.2)
    out.fg = sample_bicubic(af.expand({B, 3, m_fg.height, m_fg.width}), out.uv_fg);
    out.alpha = up(alpha(p).permute({0, 3, 1, 2}));
    out.sharp = out.alpha * out.fg + (1.0 - out.alpha) * out.bg;  // paper eq. 1
    return out;
}

torch::Tensor PaperModel::rigidity(Layer& l, const torch::Tensor& pts) {
    // Jacobian of M(x, y, t) in atlas px per frame px by finite differences (1 px steps).
    auto x = pts.select(1, 0), y = pts.select(1, 1), t = pts.select(1, 2);
    auto stacked = torch::cat({coords(x, y, t), coords(x + 1.0, y, t), coords(x, y + 1.0, t)}, 0);
    auto u = uv(l, stacked) * torch::tensor({l.width / 2.0f, l.height / 2.0f});
    const int64_t n = pts.size(0);
    auto u0 = u.narrow(0, 0, n), ux = u.narrow(0, n, n) - u0, uy = u.narrow(0, 2 * n, n) - u0;
    auto J = torch::stack({ux, uy}, 2);  // [N,2(u,v),2(x,y)]
    return rigidity_of(J);
}

torch::Tensor PaperModel::priors(const Layers& layers, const std::vector<int64_t>& frames,
                                 int64_t step, LossTerms& terms) {
    torch::Tensor total = torch::zeros({});
    const int64_t n = m_opts.prior_points;
    // Paper eq. 4 weighs L_reco by λ1 = 0.3; the engine weighs it by 1, so the priors of eq. 4
    // are divided by λ1 here (the same ratios; Adam is blind to the overall scale).
    const double inv_l1 = 1.0 / std::max(1e-6, m_opts.w_reco);
    // Rigidity (paper §3.5, LNA): the mappings are locally rotations.
    auto pts = sample_points(n, 2 * uint64_t(step), false);
    torch::Tensor a_pts;
    auto rigid = rigidity(m_bg, pts).mean();
    if (m_two_layers) {
        // The CPU-sized foreground atlas covers the subject only: judge M_f where α says the
        // foreground is seen.
        a_pts =
            alpha(coords(pts.select(1, 0), pts.select(1, 1), pts.select(1, 2))).squeeze(1).detach();
        rigid = rigid + (rigidity(m_fg, pts) * a_pts).sum() / a_pts.sum().clamp_min(1.0);
    }
    total = total + inv_l1 * m_opts.w_rigid * rigid;
    terms["rigid"] = rigid.item<double>();

    // Flow (paper §3.5, LNA): p and its flow correspondence at t + 1 map to one atlas point.
    if (m_data.flow_fwd.defined() && m_data.frames > 1) {
        auto fp = sample_points(n, 2 * uint64_t(step) + 1, true);
        const int64_t H = m_data.height, W = m_data.width;
        auto x = fp.select(1, 0), y = fp.select(1, 1), t = fp.select(1, 2);
        auto lin = t.to(torch::kLong) * (H * W) + y.to(torch::kLong) * W + x.to(torch::kLong);
        auto fu = m_data.flow_fwd.select(1, 0).reshape({-1}).index_select(0, lin);
        auto fv = m_data.flow_fwd.select(1, 1).reshape({-1}).index_select(0, lin);
        auto valid = m_data.flow_valid.reshape({-1}).index_select(0, lin);
        auto p0 = coords(x, y, t), p1 = coords(x + fu, y + fv, t + 1.0);
        auto both = torch::cat({p0, p1}, 0);
        auto ub = uv(m_bg, both);
        auto db = (ub.narrow(0, 0, n) - ub.narrow(0, n, n)).norm(2, 1);
        torch::Tensor flow;
        if (m_two_layers) {
            auto al = alpha(both).squeeze(1);
            auto a0 = al.narrow(0, 0, n);
            auto uf = uv(m_fg, both);
            auto df = (uf.narrow(0, 0, n) - uf.narrow(0, n, n)).norm(2, 1);
            auto ad = a0.detach();
            flow = (valid * (ad * df + (1.0 - ad) * db)).sum() / valid.sum().clamp_min(1.0) +
                   (valid * (a0 - al.narrow(0, n, n)).abs()).sum() / valid.sum().clamp_min(1.0);
        } else {
            flow = (valid * db).sum() / valid.sum().clamp_min(1.0);
        }
        total = total + inv_l1 * m_opts.w_flow * flow;
        terms["flow"] = flow.item<double>();
    }

    if (m_two_layers) {
        // Sparsity (paper §3.5, LNA): foreground colour where α is small should be zero.
        auto sparse = ((1.0 - layers.alpha) * layers.fg).pow(2).sum(1).mean();
        // Ramped in (0 before sparsity_start, full weight sparsity_ramp steps later): at full
        // weight from step 0 it outweighs the reconstruction ~300:1 on the soft mask edges and,
        // through the decoder shared with the background, pulls both atlases to black.
        const double ramp =
            m_opts.sparsity_ramp > 0
                ? std::clamp(double(step - m_opts.sparsity_start) / m_opts.sparsity_ramp, 0.0, 1.0)
                : (step >= m_opts.sparsity_start ? 1.0 : 0.0);
        total = total + inv_l1 * ramp * m_opts.w_sparsity * sparse;
        terms["sparsity"] = sparse.item<double>();
        // Mask bootstrap (LNA §3.3), decaying.
        const double decay = std::pow(0.5, double(step) / m_opts.bootstrap_halflife);
        auto idx = torch::tensor(frames, torch::kLong);
        auto boot = (layers.alpha - m_data.mask.index_select(0, idx)).abs().mean();
        total = total + m_opts.w_bootstrap * decay * boot;
        terms["bootstrap"] = boot.item<double>();
    }
    return total;
}

torch::Tensor PaperModel::atlas_bg() {
    torch::NoGradGuard g;
    return m_decoder->forward(m_bg.noise)[0].detach();
}

torch::Tensor PaperModel::atlas_fg() {
    if (!m_two_layers) return torch::Tensor();
    torch::NoGradGuard g;
    return m_decoder->forward(m_fg.noise)[0].detach();
}

void PaperModel::set_atlas_bg(const torch::Tensor&) {
    throw Error("the paper preset cannot import an edited atlas; use the fast preset");
}
void PaperModel::set_atlas_fg(const torch::Tensor&) {
    throw Error("the paper preset cannot import an edited atlas; use the fast preset");
}

std::map<std::string, torch::Tensor> PaperModel::state() {
    std::map<std::string, torch::Tensor> s;
    auto add = [&](const std::string& prefix, torch::nn::Module& m) {
        for (auto& kv : m.named_parameters(true)) s[prefix + kv.key()] = kv.value();
    };
    add("decoder.", *m_decoder);
    add("map_bg.", *m_bg.map);
    s["noise_bg"] = m_bg.noise;
    if (m_two_layers) {
        add("map_fg.", *m_fg.map);
        add("alpha.", *m_alpha);
        s["noise_fg"] = m_fg.noise;
    }
    return s;
}

}  // namespace refocus
