#pragma once
// The real-time preview's CPU twin: the same math, sampling, loop order and normalisation as the
// GLSL passes in shaders/ (composite.frag, dof_prep.frag, dof_tiles.frag, dof.frag). The studio
// runs the GLSL passes (ui/gl_preview.h); tests/gl/test_gl_preview.cpp holds the two together.
// Plain C++ (no torch, no GL), float arithmetic like the shaders.
//
// Composite (paper eq. 1):  C = α·A_f(M_f(p)) + (1 − α)·A_b(M_b(p)).
//   M_f, M_b: per-frame UV maps, atlas coordinates in [−1, 1] with the align_corners = false
//   convention (texel centre i of an N-texel axis sits at (2i + 1)/N − 1), i.e. pixel
//   coordinate x = ((u + 1)·N − 1)/2; bilinear, clamped to the border texels.
//
// Depth of field, layered: the background is blurred, the foreground's premultiplied colour α·F
// and α are blurred with the foreground's radius, and composited over it, so an in-focus edge
// never bleeds onto a blurred layer behind it and a blurred edge reveals the background layer
// (which holds what is hidden):  out = F̂ + (1 − Â)·B̂.
//   Radius (seed 001 eq. 1.12, linear in inverse depth): r = aperture·|invdepth − focus|, px,
//   clamped to [0, max_radius]; a non-finite r (NaN/Inf inverse depth) is 0.
//   Highlight boost, before the blur: c' = c·(1 + g·max(0, L(c) − T)·clamp(r − ½, 0, 1)),
//   L = Rec. 709 luminance; sharp pixels (r ≤ ½) are never changed.
//   Scatter-as-gather: source q reaches p when ρ(p − q) < r_q + ½, with weight
//     w(p, q) = k(r_q − ρ)·clamp(r_q − ρ + ½, 0, 1) / K(r_q),
//   k the paper's disk kernel (eq. 2): k = e^{βd}/(e^{βd} − d), d = r − ρ (bright rim at
//   d = 1/β), the clamp a half-pixel anti-aliased edge, K(r) = Σ_o k·clamp over all offsets (the
//   kernel's discrete area: per-source normalisation), ρ the Euclidean distance (circle) or the
//   polygon distance for n blades, ρ_n = ρ·cos(φ' − π/n)/cos(π/n), φ' the angle from a vertex
//   modulo 2π/n (so ρ_n = r on the polygon with circumradius r).
//   Per layer: F̂ = Σ_q w·a_q·c'_q / Σ_q w,  Â = Σ_q w·a_q / Σ_q w  (a = α for the foreground,
//   1 for the background), over the sources inside the image.
//   Early pass-through: a pixel whose neighbourhood (its kTileSize tile grown by max_radius)
//   holds no r ≥ ½ takes one tap — itself; aperture 0 is the plain composite.
// Non-finite inputs: a NaN/±Inf colour, UV or alpha value counts as 0 (then α is clamped to
// [0, 1]); a NaN/±Inf inverse depth gives r = 0 (sharp); the outputs are always finite.
#include <vector>

#include "io/image.h"

namespace refocus {

struct PreviewLens {
    double aperture = 0.0;  // px of blur radius per unit of inverse depth (0: sharp composite)
    double focus = 0.0;     // the inverse depth in focus
    double beta = 2.0;      // disk kernel rim (paper eq. 2), > 1/e
    double highlight_threshold = 1.0;  // luminance above which highlights are boosted
    double highlight_gain = 0.0;       // 0: no boost
    int blades = 0;                    // 0: circle; ≥ 3: regular polygon
    double rotation_deg = 0.0;  // blades: direction of a vertex, from +x towards +y (image down)
    double max_radius = 32.0;   // radius clamp and gather window, px, in [0, kPreviewMaxRadius]
};

constexpr double kPreviewMaxRadius = 64.0;
constexpr int kPreviewTileSize = 8;   // px per side of the early-out tiles
constexpr int kPreviewAreaSteps = 8;  // kernel-area table entries per px of radius

// Throws refocus::Error for a non-finite or out-of-range field, naming it.
void check_preview_lens(const PreviewLens& lens);

// The frame's layers, as the composite pass writes them (all width × height).
struct PreviewLayers {
    Image composite;   // 3 channels: C (eq. 1)
    Image background;  // 3 channels: A_b(M_b(p))
    Image foreground;  // 3 channels: A_f(M_f(p)), straight (not premultiplied)
    Image alpha;       // 1 channel in [0, 1]
};

// Inverse depth of each layer at the frame's pixels; an empty image means the constant.
struct PreviewDepth {
    Image background;  // 1 channel, width × height, or empty
    Image foreground;  // 1 channel, width × height, or empty
    float background_const = 0.0f;
    float foreground_const = 0.0f;
};

// Paper eq. 1. Atlases have ≥ 3 channels (extra ones ignored), UV maps 2 channels and the alpha
// map 1 channel, all three the frame's size. `foreground_atlas` may be empty (one-layer clip):
// then F = 0 and α = 0, and `foreground_uv`/`alpha` are ignored. Throws refocus::Error on
// mismatched sizes or channel counts.
// `background_fix` / `foreground_fix` (3 channels, frame size; empty: none) are added to the
// sampled layers before eq. 1: what the exported plate adds over the atlases (the output rules
// and the low-frequency lock, FrameMaps in edit/recompose.h), so that the preview shows it.
PreviewLayers composite_layers(const Image& background_atlas, const Image& background_uv,
                               const Image& foreground_atlas, const Image& foreground_uv,
                               const Image& alpha, int threads = 1,
                               const Image& background_fix = Image(),
                               const Image& foreground_fix = Image());

// Layered depth of field of `layers` (composite may be empty) → 3 channels, linear light.
// `threads` splits rows. Throws refocus::Error on a bad lens or mismatched sizes.
Image render_dof(const PreviewLayers& layers, const PreviewDepth& depth, const PreviewLens& lens,
                 int threads = 1);

// ---- Building blocks shared with the GL side (uploaded as tables, so both read equal bits) --

// The paper's eq. 2 without overflow: d > 0 uses 1/(1 − d·e^{−βd}).
float disk_kernel(float d, float beta);

// Half-width of the gather window: floor(max_radius + ½) (a source at r ≤ max_radius reaches
// no further).
int preview_window(const PreviewLens& lens);

// ρ(o) for every offset o = p − q in the window, [2D+1][2D+1] row-major, D = preview_window.
std::vector<float> preview_shape_table(const PreviewLens& lens);

// K(r) at r = i / kPreviewAreaSteps, i = 0 … ceil(max_radius·steps) + 1; linear in between.
std::vector<float> preview_area_table(const PreviewLens& lens, const std::vector<float>& shape);

// preview_lib.glsl atlas_coord: atlas coordinate u ∈ [−1, 1] (align_corners = false) on an
// n-texel axis → the bilinear pair i0, i1 = min(i0 + 1, n − 1) and the weight f of i1, clamped to
// the border texels; a non-finite u counts as 0. (For atlas-space data such as edit/depth.h.)
void preview_atlas_coord(float u, int n, int& i0, int& i1, float& f);

// r for one inverse depth: aperture·|invdepth − focus| clamped to [0, max_radius], 0 if not
// finite.
float preview_radius(float invdepth, const PreviewLens& lens);

}  // namespace refocus
