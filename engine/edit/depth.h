#pragma once
// Inverse depth for refocusing: a 1-channel inverse-depth atlas per layer, the clip's own focus
// per frame and a per-frame depth offset of the foreground layer, fitted to the fit's radius
// maps (FitData::radius) through the thin-lens law (seed 001 eq. 1.12): the blur radius is linear
// in inverse depth, r_t(p) = A·|d_t(p) − f_t|. A is fixed to 1: inverse depth is measured in px
// of blur at the clip's own aperture ("aperture 1 = as shot"), so PreviewLens{aperture = 1,
// focus = f_t} reproduces the clip's radius and aperture 0 is the sharp composite.
//
// Model, per frame t and pixel p (layers of paper eq. 1, atlas UVs in [−1, 1], align_corners =
// false, bilinear and clamped to the border texels as in render/preview.h):
//   d_t(p) = D_b(M_b(p))            where α_t(p) ≤ ½ (or one layer),
//   d_t(p) = D_f(M_f(p)) + o_t      where α_t(p) > ½  (the subject moves in depth as a whole),
//   minimise  Σ_t Σ_p (r_t(p) − |d_t(p) − f_t|)²  over D_b, D_f, f_t, o_t.
//
// Method (fit_depth): alternating exact 1-D minimisations. Each unknown z (an atlas texel's
// depth, a frame's focus, a frame's foreground offset) with the others fixed solves
//   min_z Σ_i w_i (r_i − |z − a_i|)²,
// which is piecewise quadratic with breakpoints at the a_i: between two breakpoints the signs
// s_i = sign(z − a_i) are fixed and the cost is Σ w_i (z − (a_i + s_i r_i))², minimised by a
// clamped weighted mean; a sweep over the sorted a_i finds the global minimum exactly. Texels:
// the frame pixels are splatted to the atlas bilinearly (weights), aggregated per (texel, frame),
// a_i = f_t (− o_t for the foreground). Focus: a_i = d_t(p) over the frame's pixels. Offsets:
// a_i = f_t − D_f(M_f(p)) over the frame's foreground pixels, then mean(o) = 0 (moved into D_f).
// Initial focus: the distance |f_t − f_t'| is the median radius at t' of the background texels
// sharpest at t; classical multidimensional scaling on a line of that T×T matrix gives f_t up to
// sign and shift. The rounds stop when the cost stops falling. Texels no frame saw are filled by
// push-pull (weighted pyramid down, then up) from their neighbours.
//
// Ambiguities and the rules that resolve them:
//  - |d − f| is symmetric: with a constant focus (or a texel seen in one frame) a texel's side
//    of the focal plane is not identifiable. With a varying focus the data decide. Where the two
//    sides fit equally (within DepthFitOptions::tie_px2 of mean squared error), the texel takes
//    the side where its confident neighbours lie (push-pull of the texels the data decided) when
//    they clearly lie on one side (off the midpoint by more than a quarter of the gap), else
//    the rule: the background goes behind the focal plane (smaller inverse depth) and the
//    foreground in front of it (larger). A moving camera's parallax field, where the fit has
//    one, decides the background's ties before the neighbours and the rule: it orders the
//    scene's depths whatever the focus did.
//  - The whole solution mirrored (d, f, o → −d, −f, −o) fits equally: the mirror kept is the
//    one with the foreground nearer than the background (median inverse depth), or with one
//    layer the one where most pixels lie behind the focal plane.
//  - d and f shifted together fit equally: the shift puts the farthest point (the smallest
//    inverse depth over both atlases and all frames) at 0.
// Non-finite radius or UV values are skipped; results are always finite.
#include <torch/types.h>

#include <cstdint>
#include <vector>

#include "io/image.h"
#include "render/preview.h"
#include "util/fs.h"

namespace refocus {

class FitEngine;

struct DepthFitOptions {
    int max_rounds = 12;
    double tie_px2 = 0.01;      // side-of-focus ties: mean squared error difference, px²
    int focus_samples = 20000;  // pixels per frame used by the focus/offset updates (strided)
    double stop_rel = 1e-4;     // stop when a round lowers the cost by less than this share
};

struct DepthModel {
    static constexpr int kVersion = 1;
    enum Layer { Background = 0, Foreground = 1 };

    Image bg_atlas;                // 1 channel inverse depth at the background atlas' size
    Image fg_atlas;                // 1 channel at the foreground atlas' size; empty: one layer
    std::vector<float> focus;      // f_t per frame (inverse depth in focus as shot)
    std::vector<float> fg_offset;  // o_t per frame (0 with one layer)
    double rms_px = 0.0;           // rms of r − |d − f| over the fitted pixels, px
    int rounds = 0;                // alternating rounds run
    int64_t fit_step = -1;         // the fit's step it was built from (-1: unknown)

    int frames() const { return static_cast<int>(focus.size()); }
    bool has_fg() const { return !fg_atlas.empty(); }

    // Inverse depth of each layer at frame t's pixels through its UV maps (2 channels; uv_fg may
    // be empty with one layer), foreground offset included: the preview's depth input.
    PreviewDepth frame_depth(int t, const Image& uv_bg, const Image& uv_fg) const;
    // Click to focus: the inverse depth of the layer seen at pixel (x, y) of frame t (the
    // foreground where alpha > ½). alpha may be empty with one layer.
    float depth_at_pixel(int t, int x, int y, const Image& uv_bg, const Image& uv_fg,
                         const Image& alpha) const;
    // Tracking: the inverse depth of atlas point (u, v) ∈ [−1, 1]² of `layer` at frame t.
    float depth_at_atlas(int layer, float u, float v, int t) const;
    // The visible surface's inverse depth (the foreground where alpha > ½), 1 channel.
    Image depth_map(int t, const Image& uv_bg, const Image& uv_fg, const Image& alpha) const;

    // dir/depth_bg.exr, dir/depth_fg.exr (two layers), dir/depth.json (written last), atomic.
    void save(const fs::path& dir) const;
    // Validates everything; throws refocus::Error naming the file and the problem.
    static DepthModel load(const fs::path& dir);
    static bool exists(const fs::path& dir);
};

// radius [T,H,W] px; uv_bg, uv_fg [T,H,W,2]; alpha [T,1,H,W]. uv_fg/alpha undefined (or a
// zero-size fg atlas) for one layer. See the header comment for the model and method.
// `bg_parallax` [bg_h,bg_w] (optional): the background's parallax field (plane + parallax,
// fit/fast_model.h), relative inverse depth up to an affine map; where the radius leaves a
// texel's side of the focal plane open, the side that follows γ is taken (depth_fit.cpp).
DepthModel fit_depth(const torch::Tensor& radius, const torch::Tensor& uv_bg,
                     const torch::Tensor& uv_fg, const torch::Tensor& alpha, int bg_h, int bg_w,
                     int fg_h, int fg_w, const DepthFitOptions& opts = {},
                     const torch::Tensor& bg_parallax = {});

// Renders every frame's layers (the model locked per frame) and fits depth to the engine's
// radius maps. Throws for the perframe preset (no atlas).
DepthModel build_depth(FitEngine& engine, const DepthFitOptions& opts = {});

// A project's depth folder: <project>/depth.
inline fs::path depth_dir(const fs::path& project_dir) {
    return project_dir / "depth";
}

// The project's depth for the engine's current fit: <project>/depth when it was built from this
// fit step for this many frames, else built (build_depth) and saved there. `built` tells which.
DepthModel project_depth(FitEngine& engine, const fs::path& project_dir, bool* built = nullptr);

}  // namespace refocus
