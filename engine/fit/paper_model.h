#pragma once
// The `paper` preset: paper eq. 1 with the paper's networks (seed 000 §3.1, §3.2), scaled to
// run on a CPU.
//   Mappings M_b, M_f: MLPs over p = (x, y, t) normalised to [−1, 1] with positional encoding,
//     output UV in [−1, 1] through tanh (Layered Neural Atlases, Kasten et al. 2021). UV is in
//     the grid_sample convention (align_corners = false) of an atlas laid out like the fast
//     preset's: the background atlas is the bounding box of every frame mapped through the
//     camera homography, the foreground atlas a subject-centroid-stabilised box.
//   Alpha M_α: MLP with positional encoding → sigmoid.
//   Atlases: a deep-image-prior decoder (§3.2) shared by both layers, A = D(Z) from fixed,
//     seeded noise maps Z of C × H/8 × W/8: 3 × (conv3×3 + leaky ReLU + pixel shuffle ×2), then
//     conv3×3 → 3 channels + sigmoid.
// CPU scaling (stated): MLP widths 128 (mappings 4 layers, alpha 6 layers) instead of 256/8,
// and the MLPs are evaluated on a half-resolution lattice of pixel centres, bilinearly
// interpolated to full frames (UV maps are smooth; the fast preset's alpha is quarter-res).
// Initialisation: the MLPs are pre-trained in the constructor to the homography / centroid
// coordinates and to the masks; the decoder is pre-trained to the sharpness-weighted fusion
// of the input frames (the fast preset's starting atlas), so that the reblur loss starts from
// a meaningful state instead of noise (the paper's 50k GPU iterations do not fit a CPU).
#include <torch/nn/module.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/pixelshuffle.h>

#include "fit/fit_model.h"

namespace refocus {

struct PaperModelOptions {
    // Networks (LNA: mappings 4×256, alpha 8×256; here narrower for the CPU).
    int map_layers = 4, map_width = 128, map_freqs = 2;
    int alpha_layers = 6, alpha_width = 128, alpha_freqs = 5;
    int mlp_stride = 2;             // MLPs evaluated every `mlp_stride` px, then interpolated
    int noise_channels = 32;        // C of Z_f, Z_b (H/8 × W/8)
    std::vector<int> decoder_channels{64, 48, 32};  // after each pixel-shuffle stage
    // Learning rates (Adam).
    double lr_map = 1e-4, lr_alpha = 5e-4, lr_decoder = 1e-3;
    // Loss weights of paper eq. 4 (§4.1): λ2 flow, λ3 sparsity, λ4 rigidity; λ1 (reco) is the
    // engine's FitOptions::w_reco.
    double w_flow = 1.5, w_sparsity = 100.0, w_rigid = 0.5;
    double w_bootstrap = 1.0;       // α to the masks (LNA §3.3), halves every halflife steps
    int bootstrap_halflife = 400;
    int prior_points = 2048;        // random points per step for rigidity and flow
    // Pre-training in the constructor.
    int pretrain_map_steps = 300, pretrain_atlas_steps = 300;
    double lr_pretrain_atlas = 2e-3;
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
        torch::Tensor to_atlas;         // [T,3,3] float32: frame pixel → atlas pixel (init target)
        torch::Tensor noise;            // [1,C,H/8,W/8] Z, fixed
        CoordMlp map{nullptr};          // M_b or M_f
    };
    torch::Tensor coords(const torch::Tensor& x, const torch::Tensor& y, const torch::Tensor& t) const;
    torch::Tensor lattice(const std::vector<int64_t>& frames) const;  // [B,h,w,3] normalised p
    torch::Tensor target_uv(const Layer& l, const torch::Tensor& px, const torch::Tensor& t) const;
    torch::Tensor uv(Layer& l, const torch::Tensor& p);       // [...,3] → [...,2]
    torch::Tensor alpha(const torch::Tensor& p);                   // [...,3] → [...,1]
    torch::Tensor up(const torch::Tensor& x) const;  // [B,C,h,w] lattice → [B,C,H,W]
    // src [T,C,H,W] pulled into the atlas, weighted toward the sharpest views → [C,Ha,Wa]
    torch::Tensor fused(const Layer& l, const torch::Tensor& weight, const torch::Tensor& src) const;
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
    CoordMlp m_alpha{nullptr};   // M_α
    AtlasDecoder m_decoder{nullptr};
};

}  // namespace refocus
