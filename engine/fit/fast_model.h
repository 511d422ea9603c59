#pragma once
// The `fast` preset: paper eq. 1 on explicit representations that train in minutes on a CPU.
//   Background mapping M_b: the per-frame camera homography (from prepare) into a reference
//     atlas, plus a coarse residual warp grid per frame (learned only when the camera moves).
//   Foreground mapping M_f: per-frame translation (and scale where it changes) along the
//     subject's track (atlas_geometry.h) plus a coarse residual warp grid per frame.
//   Alpha: a matte shared by the frames in the foreground atlas (half resolution) plus a per-frame
//     residual at quarter resolution (logits), bootstrapped from the masks where the subject is
//     sharp.
//   Atlases: multi-resolution textures A = Σ_l up(T_l) (coarse-to-fine for free: a coarse level
//     moves many atlas pixels at once), with total variation.
//     Their finest level holds `atlas_scale` texels per frame pixel: 2 for a moving camera
//     with the clip partly in focus (choose_atlas_scale, fit_setup.h), so that detail frames
//     saw at different sub-pixel phases is resolved rather than lost to resampling.
// Initialisation fuses the input frames into the atlases weighted toward the frames that saw
// each atlas pixel sharpest (weight (r + ½)^−4), which is where multi-frame deblurring starts.
#include <functional>

#include "model/fit_model.h"
#include "model/atlas_geometry.h"

namespace refocus {

struct FastModelOptions {
    int levels = 4;         // atlas pyramid levels
    int warp_cell_px = 32;  // residual warp grid spacing
    // A moving camera's background warps start from the optical flow (flow_warp.h), on a grid
    // this fine: parallax within the layer (a pillar sliding across a wall) is a field, not a
    // homography's error.
    bool flow_warp = false;
    int flow_warp_cell_px = 8;
    // Plane + parallax (Irani & Anandan 1996; Sawhney 1994) on a moving camera's background: frame
    // t sees atlas point u displaced by γ(u)·(a_t + b_t·(u − c_t)/R): γ one field for the clip
    // (relative inverse depth, a value per cell of `parallax_cell_px` frame px), (a_t, b_t) the
    // frame's epipole (lateral and forward translation, 3 numbers), c_t the frame's centre in the
    // atlas, R its half diagonal. Off, or on a static camera: the homography and warp alone.
    bool parallax = true;
    // ... kept only where the field the flow gives, fitted to the even frame pairs, lowers the odd
    // pairs' disagreement by this share (0: kept whenever the camera moves): depth that every
    // pair shares, not the flow's own errors (flow_warp.h, ParallaxInit).
    double parallax_evidence = 0.02;
    double parallax_travel_px = 8;  // ... and where the view travels this far (frame px)
    int parallax_cell_px = 8;
    bool parallax_homography = false;  // ... and each frame's homography corrected with it
    double lr_parallax = 0.05;         // γ, px per step at the frame of largest camera motion
    double lr_epipole = 0.002;         // (a_t, b_t), normalised to at most 1 over the clip
    double w_parallax = 0.005;         // γ smoothness
    double lr_atlas = 0.01;
    double lr_warp = 0.05;  // px per step (Adam)
    double lr_alpha = 0.05;
    double w_tv = 0.002;  // atlas TV weight
    // ... times clamp(gain · r, 1, cap) on texels seen at one radius r in every frame (losses.h,
    // tv_radius_factor; cap 1: uniform): where the radii seen vary by less than `spread` px
    // and r < fade px (fading to 1 from fade − 1).
    double tv_radius_cap = 4.0;
    double tv_radius_gain = 2.0;
    double tv_radius_spread = 1.0;
    double tv_radius_fade = 5.0;  // background atlas only
    double tv_radius_layers = 3;  // which atlases: 1 background, 2 foreground, 3 both
    double w_warp = 0.01;         // residual warp smoothness
    // Neighbouring frames' residual warps and mattes agree. Off: the residual corrects each
    // frame's own homography error (hand shake, a blurred frame's weak tracks), and pulling it
    // toward the neighbours' keeps those errors (docs/method.md, Model).
    double w_temporal = 0.0;
    double w_bootstrap = 0.5;  // alpha to mask, halves every `bootstrap_halflife` steps
    int bootstrap_halflife = 400;
    double w_alpha_residual = 0.02;      // L1 on the per-frame alpha residual (logit)
    double alpha_shared_lr = 1.0;        // the shared matte's learning rate, times lr_alpha
    int align_rounds = 2;                // ECC refinement rounds at initialisation (0: off)
    int align_width = 640;               // ... on frames shrunk to at most this wide (0: full size)
    std::string align_motion = "shift";  // a moving camera's ECC: shift|affine|homography
    double align_max_px = 4;   // ... and no corner of a moving camera's frame moves this far
    bool static_align = true;  // ... also on a camera judged static (hand shake)
    double atlas_scale = 1;    // atlas px per frame px (FitData::atlas_scale); TV and the
                               // residual warps stay in frame px
    // The deblurring path: a second parameterisation of each atlas, d * Q, where Q's response
    // rises where the layer's typical blur attenuates the scene (make_deblur_path). Adam moves
    // each texel by ~lr whatever its gradient's size, so detail that the blur passed at a few
    // percent converges that much slower on the texels alone; through Q it does not. Off by
    // default: on the rendered corpus's dev clips (sensor and render noise, estimated radius)
    // its gain turns noise and radius errors into ringing (docs/method.md, Deblurring path).
    bool deblur_path = false;
    double deblur_eps = 0.003;       // Q's gain is capped at ~1/sqrt(eps)
    double deblur_lr = 0.3;          // times lr_atlas
    double deblur_min_radius = 2.0;  // px: a layer blurred less has no path
    int deblur_kernel = 15;          // Q's support, px
    double deblur_tv = 1.0;          // TV weight factor on an atlas with the path
    double deblur_tv_given = 0.5;    // ... where the radius is given (FitData::radius_given)
    // Frames per step when a layer has the path (FitOptions::batch left to the model): its
    // texels take the data's gradient through Q's gain, and two frames' worth of it is noisy.
    int deblur_batch = 4;
    // The set-up of a model whose checkpoint is loaded next (export, the studio, `atlas`): the
    // atlases, the matte and the parallax field are not fused or fitted from the frames, since
    // the checkpoint replaces them. Training from such a set-up starts from empty atlases.
    // A crop step reads each frame's box of an atlas where the boxes of its frames together
    // cover under this share of the atlas: each box costs its texels, and the atlas once more
    // in the backward (the finest level's gradient); 384x288 crops read most of theirs.
    double window_share = 0.5;
    bool restore_only = false;
    int pad = 0;  // px of scene the atlases hold beyond each frame edge (the
                  // engine passes the largest blur support; FitModel::max_pad)
};

// [1,C,h,w] prefiltered for a footprint of s × s texels (a layer seen s times smaller than in
// its atlas): a separable Gaussian of variance (s² − 1)/12 texels² a side, edges repeated; the
// image itself where that is under 0.01 (s ≤ ~1.06).
torch::Tensor prefilter_for_footprint(const torch::Tensor& image, double s);
// The same by LibTorch's depthwise conv2d: the reference the fast path is tested against.
torch::Tensor prefilter_for_footprint_reference(const torch::Tensor& image, double s);
// How far that prefilter reaches, texels (0 where it returns the image itself).
int64_t prefilter_reach(double s);

class FastModel : public FitModel {
  public:
    FastModel(const FitData& data, const FastModelOptions& opts);
    std::string preset() const override { return "fast"; }
    std::vector<ParamGroup> param_groups() override;
    Layers render(const std::vector<int64_t>& frames) override { return render_padded(frames, 0); }
    int64_t max_pad() const override { return m_opts.pad; }
    int preferred_batch() const override;
    std::string preferred_batch_reason() const override;
    Layers render_padded(const std::vector<int64_t>& frames, int64_t pad) override;
    // Samples the atlases, the warps and the matte at the windows' pixels only.
    Layers render_window(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                         const std::vector<int64_t>& y0, int64_t h, int64_t w) override;
    torch::Tensor priors(const Layers& layers, const std::vector<int64_t>& frames, int64_t step,
                         LossTerms& terms) override;
    torch::Tensor atlas_bg() override;
    torch::Tensor atlas_fg() override;
    torch::Tensor parallax_bg() override;
    void set_atlas_bg(const torch::Tensor& rgb) override;
    void set_atlas_fg(const torch::Tensor& rgb) override;
    std::map<std::string, torch::Tensor> state() override;
    void load_state(const std::map<std::string, torch::Tensor>& s) override;

  private:
    struct Atlas {
        int64_t width = 0, height = 0;
        double scale = 1;                   // atlas px per frame px
        double origin_x = 0, origin_y = 0;  // atlas pixel (0,0) in mapped coordinates
        std::vector<torch::Tensor> levels;  // [1,3,h_l,w_l], coarse → fine
        torch::Tensor to_atlas;             // [T,3,3] float32: frame pixel → atlas pixel
        torch::Tensor warp;                 // [T,2,gh,gw] residual, px
        bool learn_warp = false;
        torch::Tensor parallax;       // [1,1,gh,gw] γ over the atlas (undefined: no parallax)
        torch::Tensor epipole;        // [T,3] (a_x, a_y, b) per frame
        torch::Tensor centre;         // [T,2] each frame's centre in atlas px
        double parallax_radius = 1;   // R: half the frame's diagonal in atlas px
        torch::Tensor tv_weight;      // [1,1,Ha,Wa] TV weight per texel (undefined: 1)
        torch::Tensor deblur;         // [1,3,h,w] the deblurring path's texels, frame px
        torch::Tensor deblur_kernel;  // [3,1,k,k] its fixed filter
    };
    // Gives `a` its deblurring path if the layer was never seen in focus; returns the log line.
    std::string make_deblur_path(Atlas& a, const torch::Tensor& radius, const torch::Tensor& weight,
                                 const torch::Tensor& views, const char* name);
    torch::Tensor compose(const Atlas& a) const;
    // Atlas pixel coordinates of frame pixels, `pad` px beyond the edges: [B,H+2pad,W+2pad,2].
    torch::Tensor map_coords(const Atlas& a, const std::vector<int64_t>& frames,
                             int64_t pad = 0) const;
    // The same over windows of h × w px at (x0[b], y0[b]) (render_window): [B,h,w,2].
    torch::Tensor map_coords_window(const Atlas& a, const std::vector<int64_t>& frames,
                                    const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                                    int64_t h, int64_t w) const;
    torch::Tensor to_grid(const Atlas& a, const torch::Tensor& px) const;  // → [-1,1]
    // Frames' atlas coordinates px [B,2,h,w] moved by the plane + parallax term (identity where
    // the atlas has none).
    torch::Tensor add_parallax(const Atlas& a, const torch::Tensor& idx,
                               const torch::Tensor& px) const;
    // Gives `a` its parallax field and epipoles, started from the homographies: a_t the frame
    // centre's travel in the atlas since frame 0, b_t its change of scale; γ = 0 (the first step
    // renders what the homographies do) unless the flow says more. Returns the log line.
    // With the flow, γ and the epipoles start from it (flow_warp.h) over `region(t)`.
    std::string make_parallax(Atlas& a, const std::function<torch::Tensor(int64_t)>& region);
    static torch::Tensor parallax_smoothness(const torch::Tensor& g);
    // Frames over windows (render_window), or with `pad` ≥ 0 the frames padded by `pad` px,
    // sampled over the whole padded frame (render_padded).
    Layers render_region(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                         const std::vector<int64_t>& y0, int64_t h, int64_t w, int64_t pad);
    // Whether `layers` cover whole frames (render_padded), not windows (render_window).
    bool covers_frames(const Layers& layers) const;
    // The mask bootstrap's L1 over the part of the rendered layers that lies in the frame.
    // How far the masks are trusted where the subject's radius is `subject_r` (sharp: most).
    static torch::Tensor boot_weight(const torch::Tensor& subject_r);
    torch::Tensor bootstrap_l1(const Layers& layers, const std::vector<int64_t>& frames) const;
    // Over windows, each prior covers the part of an atlas or a per-frame grid that the windows
    // read, as a mean like the whole frames' (fast_model_window.cpp): one that reached further
    // would move parameters no loss pulls on this step by Adam's full step (docs/method.md,
    // Crops). `uv` [B,h,w,2] is the windows' atlas grid.
    // The part of an atlas that one window reads (the crop step): texels [x0, x0 + w) ×
    // [y0, y0 + h), composed. A 1080p atlas is some twenty crops' boxes; composing, prefiltering
    // and sampling all of it forward and backward at every step cost the step its speed.
    struct AtlasWindow {
        int64_t x0 = 0, y0 = 0, w = 0, h = 0;
        double footprint = 1;    // texels per frame px the box is prefiltered for (1: none)
        torch::Tensor composed;  // [1,3,h,w]
    };
    // The box that bicubic taps at atlas px [h,w,2] read, grown by `grow` texels.
    AtlasWindow window_box(const Atlas& a, const torch::Tensor& px, int64_t grow) const;
    // The frames' boxes of `a` (px [B,h,w,2]; `minify`: grown by the foreground's prefilter) where
    // together they cover under fast.window_share of it, else none (compose the atlas whole).
    std::vector<AtlasWindow> paying_windows(const Atlas& a, const torch::Tensor& px,
                                            const std::vector<int64_t>& frames, bool minify) const;
    void compose_window(const Atlas& a, AtlasWindow& win) const;  // fills win.composed
    // Each window composed, prefiltered for its footprint and sampled at px [B,h,w,2]
    // ([B,3,h,w]); the composed windows go to `keep`.
    torch::Tensor sample_windows(const Atlas& a, const torch::Tensor& px,
                                 std::vector<AtlasWindow> wins,
                                 std::vector<AtlasWindow>* keep) const;
    // Texels of the foreground atlas per frame px in frame t, over the atlas's own scale.
    double footprint(int64_t t) const;
    // TV over the boxes the windows read: from `wins` (the render's) where they hold the box,
    // else from the atlas composed whole (`composed`, or composed here where undefined).
    torch::Tensor window_tv(const Atlas& a, const std::vector<AtlasWindow>& wins,
                            const torch::Tensor& composed, const torch::Tensor& uv) const;
    torch::Tensor window_warp(const Atlas& a, const Layers& layers,
                              const std::vector<int64_t>& frames) const;
    torch::Tensor window_alpha_residual(const Layers& layers,
                                        const std::vector<int64_t>& frames) const;
    // Smoothness of residual warps [B,2,gh,gw] (and a little of their size).
    static torch::Tensor warp_smoothness(const torch::Tensor& w);
    void init_levels(Atlas& a, const torch::Tensor& fused);
    // Frames (or `what`, [T,C,H,W] in frame px) fused into the atlas, sharpest-weighted.
    // With `with_warp`, pulled back through the residual warps too.
    torch::Tensor fuse(const Atlas& a, const torch::Tensor& weight, const torch::Tensor& what = {},
                       bool with_warp = false) const;
    // The same with each frame's weight ([1,H,W]) and source ([C,H,W]) made on demand: no
    // clip-sized arrays of derived maps.
    using FrameFn = std::function<torch::Tensor(int64_t)>;
    torch::Tensor fuse(const Atlas& a, const FrameFn& weight, const FrameFn& what,
                       bool with_warp = false, const std::function<TexelBox(int64_t)>& window = {},
                       const torch::Tensor& fallback = {}) const;
    // The frames fused where `region(t)` ([1,H,W]) holds the layer: frames wider than the
    // alignment's proxy are pulled in over their region's box only, and the texels no box
    // reaches take the fusion on the proxy (fuse_frames' window and fallback). The subject of a
    // 1080p clip is a few percent of each frame; its atlas spans its whole track.
    // `weight_p` (optional): the weights on the proxy, as shrunk_once gives them.
    torch::Tensor fuse_regions(const Atlas& a, const FrameFn& weight, const FrameFn& region,
                               const FrameFn& weight_p = {}) const;
    // `full` shrunk to the alignment's proxy, each frame once, when first read (the subject's
    // alignment rounds and its atlas's fallback read the same frames and weights); empty on
    // frames no wider than the proxy.
    FrameFn shrunk_once(FrameFn full) const;
    FrameFn m_input_p;         // the input frames on the proxy during the set-up (shrunk_once)
    void update_tv_weights();  // each atlas's tv_weight, from the data and its geometry
    // The TV weights wait for the first priors(): a fused pass over every frame that an export
    // or a reopened project (renders only) never needs, and a resumed fit makes once.
    bool m_tv_stale = true;
    torch::Tensor tv_weight_map(const Atlas& a, const FrameFn& radius, const FrameFn& weight,
                                const FrameFn& views, double fade) const;
    void set_atlas(Atlas& a, const torch::Tensor& rgb);
    static void rescale(Atlas& a, double s);
    // The composed foreground atlas ([3,h,w] or [1,3,h,w]) prefiltered for each frame's
    // minification (the subject seen smaller than in the atlas): [B,3,h,w].
    torch::Tensor minified(const torch::Tensor& fg, const std::vector<int64_t>& frames) const;
    // Refines each frame's mapping by ECC image alignment (Evangelidis & Psarakis 2008) of the
    // reblurred fused atlas against the input frame, inside `region` (frame t's [1,H,W] > 0.5;
    // `weight` frame t's fusion weight, `weight_p` optionally the same on the proxy), then
    // re-fuses. Chained feature homographies drift by a pixel or more over a clip, and a sharp
    // atlas shifted by a pixel scores worse than the blurred input. `only` (if given): the frames
    // aligned, the others keep their mapping; `rounds` < 0: fast.align_rounds.
    void refine_alignment(Atlas& a, const FrameFn& weight, const FrameFn& weight_p,
                          const FrameFn& region, double max_shift, bool static_camera = false,
                          const std::vector<int64_t>* only = nullptr, int rounds = -1);
    // Checkpoints hold each atlas's geometry (its box and per-frame mapping) beside its texels:
    // a reopened project keeps what its fit trained, even where this build would place the
    // atlas differently. A state without geometry keeps the one just computed from the data.
    static torch::Tensor geometry(const Atlas& a);
    void adopt_geometry(Atlas& a, const std::string& name, std::map<std::string, torch::Tensor>& s);

    const FitData& m_data;
    FastModelOptions m_opts;
    torch::Tensor m_pixels;      // [H*W,3] homogeneous pixel centres
    torch::Tensor m_pixels_pad;  // the same over the frame padded by opts.pad
    Atlas m_bg, m_fg;
    bool m_two_layers = false;
    torch::Tensor m_alpha_logit;  // [T,1,H/4,W/4] per-frame residual logit
    torch::Tensor m_alpha_atlas;  // [1,1,h,w] shared matte logit, foreground atlas at half size
    int64_t m_alpha_h = 0, m_alpha_w = 0;
    torch::Tensor m_composed_bg, m_composed_fg;  // of the last training render (see render_padded)
    // Outside training the atlases hold still from frame to frame (an export, playback): each is
    // composed once and kept while its tensors stay the same ones at the same versions (an edit,
    // an import or a loaded state changes them).
    struct StillAtlas {
        std::vector<torch::Tensor> parts;  // held, so that no new tensor takes their place
        std::vector<int64_t> versions;
        torch::Tensor composed;
    };
    mutable StillAtlas m_still_bg, m_still_fg;
    torch::Tensor compose_still(const Atlas& a, StillAtlas& memo) const;
    std::vector<AtlasWindow> m_windows_bg, m_windows_fg;  // of the last training render_window
};

}  // namespace refocus
