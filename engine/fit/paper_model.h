#pragma once
// The `paper` preset: paper eq. 1 with the paper's networks (seed 000 §3.1, §3.2), scaled to
// run on a CPU.
//   Mappings M_b, M_f: MLPs over p = (x, y, t) normalised to [−1, 1] with positional encoding
//     (Layered Neural Atlases, Kasten et al. 2021). UV is in the grid_sample convention
//     (align_corners = false) of an atlas laid out like the fast preset's: the background atlas
//     is the bounding box of every frame mapped through the camera homography, the foreground
//     atlas a box stabilised on the subject's track (no larger than the background's).
//   Alpha M_α: MLP with positional encoding → sigmoid.
//   Atlases: a deep-image-prior decoder (§3.2) shared by both layers, A = D(Z) from fixed,
//     seeded noise maps Z of C × H/8 × W/8: 3 × (conv3×3 + leaky ReLU + pixel shuffle ×2), then
//     conv3×3 → 3 channels + sigmoid.
//   Loss weights of §4.1: λ1..λ4 = 0.3, 1.5, 100, 0.5 (see priors()).
// Deviations, each for the CPU budget (docs/method.md, Presets):
//   - M_b, M_f output a bounded residual (tanh × residual_px) added to the geometric mapping
//     (homography / stabilising translation) instead of UV directly, the residual's last layer
//     starting at zero. LNA pre-trains a direct MLP to that mapping; the pixels of mapping
//     error a CPU's few hundred pre-training steps leave undo the deblurring by themselves.
//   - MLP widths 128 (mappings 4 layers, alpha 6 layers) instead of 256/8, evaluated on a
//     lattice every mlp_stride = 4 px and bilinearly interpolated (the residual and α are
//     smooth; the geometric part is evaluated at every pixel).
//   - Sparsity (λ3) is ramped in over steps sparsity_start … + sparsity_ramp: at full weight
//     from the start it outweighs the reconstruction ~300:1 on soft mask edges and, through
//     the decoder shared with the background, pulls both atlases to black.
// Initialisation: M_α is pre-trained to the masks; the decoder is pre-trained (L1) to the
// sharpness-weighted fusion of the input frames (atlas_geometry.h fuse_frames, the fast
// preset's starting atlas), so that the reblur loss starts from a meaningful state instead of
// noise (the paper's 50k GPU iterations do not fit a CPU).
#include <torch/nn/module.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/pixelshuffle.h>

#include "model/fit_model.h"

namespace refocus {

struct PaperModelOptions {
    // Networks (LNA: mappings 4×256, alpha 8×256; here narrower for the CPU).
    int map_layers = 4, map_width = 128, map_freqs = 2;
    int alpha_layers = 6, alpha_width = 128, alpha_freqs = 5;
    int mlp_stride = 4;         // MLPs evaluated every `mlp_stride` px, then interpolated
    double residual_px = 12.0;  // largest offset M_b, M_f may add to the geometric mapping
    int noise_channels = 32;    // C of Z_f, Z_b (H/8 × W/8)
    std::vector<int> decoder_channels{64, 48, 32};  // after each pixel-shuffle stage
    // Learning rates (Adam).
    double lr_map = 1e-4, lr_alpha = 5e-4, lr_decoder = 1e-3;
    // Loss weights of paper eq. 4 (§4.1): λ2 flow, λ3 sparsity, λ4 rigidity; λ1 (reco) is the
    // engine's FitOptions::w_reco.
    double w_reco = 0.3, w_flow = 1.5, w_sparsity = 100.0, w_rigid = 0.5;
    int sparsity_start = 100, sparsity_ramp = 300;  // λ3 ramps in over these steps
    double w_bootstrap = 1.0;  // α to the masks (LNA §3.3), halves every halflife steps
    int bootstrap_halflife = 400;
    int prior_points = 2048;  // random points per step for rigidity and flow
    // Pre-training in the constructor.
    int pretrain_map_steps = 300, pretrain_atlas_steps = 300;
    // 5e-3 brings the decoded atlas closest to the fusion in 300 steps, so the fit starts from
    // a sharper atlas; an lr_decoder above 1e-3 then loses that start (docs/method.md, Presets).
    double lr_pretrain_atlas = 5e-3;
};

// LNA's MLP: positional encoding (x, sin 2^k π x, cos 2^k π x), ReLU hidden layers.
struct CoordMlpImpl : torch::nn::Module {
    CoordMlpImpl(int freqs, int layers, int width, int out);
    torch::Tensor forward(const torch::Tensor& p);  // [N,3] → [N,out] (raw)
    int freqs;
    torch::nn::Sequential net{nullptr};
};
TORCH_MODULE(CoordMlp);

// Deep-image-prior decoder with pixel shuffle (paper §3.2), shared by A_f and A_b.
struct AtlasDecoderImpl : torch::nn::Module {
    AtlasDecoderImpl(int in_channels, const std::vector<int>& channels);
    torch::Tensor forward(const torch::Tensor& z);  // [1,C,h,w] → [1,3,8h,8w] in (0,1)
    torch::nn::Sequential net{nullptr};
};
TORCH_MODULE(AtlasDecoder);

class PaperModel : public FitModel {
  public:
    PaperModel(const FitData& data, const PaperModelOptions& opts, uint64_t seed);
    std::string preset() const override { return "paper"; }
    std::vector<ParamGroup> param_groups() override;
    Layers render(const std::vector<int64_t>& frames) override;
    torch::Tensor priors(const Layers& layers, const std::vector<int64_t>& frames, int64_t step,
                         LossTerms& terms) override;
    torch::Tensor atlas_bg() override;
    torch::Tensor atlas_fg() override;
    // Throws: a decoded atlas cannot take an imported repaint (use the fast preset).
    void set_atlas_bg(const torch::Tensor& rgb) override;
    void set_atlas_fg(const torch::Tensor& rgb) override;
    std::map<std::string, torch::Tensor> state() override;

  private:
    struct Layer {
        int64_t width = 0, height = 0;  // atlas size, multiple of 8
        torch::Tensor to_atlas;        // [T,3,3] float32: frame pixel → atlas pixel (init target)
        torch::Tensor noise;           // [1,C,H/8,W/8] Z, fixed
        CoordMlp map{nullptr};         // M_b or M_f (residual over to_atlas)
        torch::Tensor residual_scale;  // [2] grid units of residual_px
        bool learn_residual = true;    // false: the geometric mapping only (static camera bg)
    };
    torch::Tensor coords(const torch::Tensor& x, const torch::Tensor& y,
                         const torch::Tensor& t) const;
    torch::Tensor lattice(const std::vector<int64_t>& frames) const;  // [B,h,w,3] normalised p
    torch::Tensor target_uv(const Layer& l, const torch::Tensor& px, const torch::Tensor& t) const;
    torch::Tensor full_lattice(const std::vector<int64_t>& frames) const;  // [B,H,W,3] every pixel
    torch::Tensor base_uv(const Layer& l, const torch::Tensor& p) const;   // geometric mapping
    torch::Tensor residual(Layer& l, const torch::Tensor& p);  // MLP offset, [...,3] → [...,2]
    torch::Tensor uv(Layer& l, const torch::Tensor& p);        // [...,3] → [...,2]
    void init_residual(Layer& l);
    torch::Tensor alpha(const torch::Tensor& p);     // [...,3] → [...,1]
    torch::Tensor up(const torch::Tensor& x) const;  // [B,C,h,w] lattice → [B,C,H,W]
    // src [T,C,H,W] pulled into the atlas, weighted toward the sharpest views → [C,Ha,Wa]
    torch::Tensor fused(const Layer& l, const torch::Tensor& weight,
                        const torch::Tensor& src) const;
    void pretrain_mappings();
    void pretrain_atlases(const torch::Tensor& fused_bg, const torch::Tensor& fused_fg);
    torch::Tensor rigidity(Layer& l, const torch::Tensor& p);
    torch::Tensor sample_points(int64_t n, uint64_t salt, bool flow_frames) const;  // [n,3] px

    const FitData& m_data;
    PaperModelOptions m_opts;
    uint64_t m_seed;
    bool m_two_layers = false;
    int64_t m_lh = 0, m_lw = 0;  // MLP lattice size
    Layer m_bg, m_fg;
    CoordMlp m_alpha{nullptr};  // M_α
    AtlasDecoder m_decoder{nullptr};
};

}  // namespace refocus
