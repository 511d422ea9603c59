#pragma once
// The aperture (light-field) renderer: depth of field by integrating over the lens aperture
// (seed 002, "Refocusing with Lightfield Array": I = 1/|A| ∫∫_A L(u, v, s + d·u, t + d·v) du dv,
// the renderer R of ARGAN). It is the ground truth for `refocus synth` and the export-quality
// refocus renderer: it is independent of the lens blur layer (engine/ops/lens_blur.h) that the
// fit uses, and unlike a single-layer scatter it gets occlusion right — where a blurred
// foreground edge covers only part of the aperture, the background behind it shows through.
//
// Model (thin lens, seed 001 eq. 1.12: the blur radius is linear in inverse depth):
//   a scene point at sharp-image position p and inverse depth d, seen through the aperture
//   point (u, v) of the unit aperture shape, lands at  p + A·(d − f)·(u, v),
//   so over the whole aperture it covers a disc (or polygon) of radius  r = A·|d − f|  px,
//   where A = `ApertureLens::aperture` (px of blur radius per unit of inverse depth) and
//   f = `ApertureLens::focus` (the inverse depth in focus). Inverse depth has any unit the
//   caller likes (1/m, or a normalised 0..1 disparity); A absorbs it.
//
// Algorithm: for each aperture sample (u, v) and each output pixel x, every layer is
// backward-warped — the source p solving x = p + s(p)·(u, v), s = A·(d − f), is found by
// fixed-point iteration from p = x − s(x)·(u, v) — sampled bilinearly (premultiplied colour
// and alpha), and the layers are composited front to back with "over"; the samples are
// averaged. Backward warping needs the warp of each layer to be invertible: within a layer the
// inverse depth must vary smoothly (|∇s| < 1, i.e. A·|∇d| < 1 px per px; a slanted plane is
// far inside this); depth discontinuities belong *between* layers, which is how the product's
// atlases (foreground over background) are organised anyway.
//
// Sampling: a Fibonacci (Vogel) spiral on the unit disc — area-uniform and low-discrepancy —
// kept inside the polygon for bladed apertures and re-centred to a zero mean. The count
// follows the largest blur in the frame: ~`samples_per_px2` samples per px² of the aperture
// shape at the largest radius (so sample spacing in the blur disc is ~1 px and the disc looks
// smooth); a frame with no blur gets exactly one sample (and is then an exact composite).
#include <array>
#include <vector>

#include "io/image.h"

namespace refocus {

enum class ApertureShape {
    Circle,  // a disc of radius r
    Blades,  // a regular polygon with `blades` vertices on the circle of radius r
};

struct ApertureLens {
    // px of blur radius per unit of inverse depth: r = aperture·|invdepth − focus| (eq. 1.12).
    // 0 renders the sharp composite.
    double aperture = 0.0;
    double focus = 0.0;  // the inverse depth in focus
    ApertureShape shape = ApertureShape::Circle;
    int blades = 6;             // Blades: ≥ 3
    double rotation_deg = 0.0;  // Blades: direction of a vertex, from +x towards +y (image down)

    // The blur radius in px of a point at inverse depth `invdepth` (circumradius for blades).
    double radius(double invdepth) const;
};

// One layer of the scene, all layers of one render having the same size. The layer holds what
// is at its depth *including what is hidden behind nearer layers* (that is what shows through
// at a blurred occlusion edge), so render layers with a margin of at least the largest blur
// radius beyond the output window (see `ApertureRenderOptions::crop_*`); samples beyond the
// layer's edge repeat its border pixels.
struct ApertureLayer {
    Image rgb;       // 3 channels, linear light
    Image alpha;     // 1 channel in [0,1]; empty: opaque
    Image invdepth;  // 1 channel; empty: `invdepth_const` everywhere
    float invdepth_const = 0.0f;
    bool premultiplied = false;  // true: `rgb` is already multiplied by `alpha`
};

struct ApertureRenderOptions {
    double samples_per_px2 = 1.0;    // aperture samples per px² of the largest blur shape
    int min_samples = 16;            // when there is any blur (≥ 1e-3 px)
    int max_samples = 4096;          // cap: beyond it (r ≳ 36 px) the sample spacing exceeds 1 px
    int samples = 0;                 // > 0: use exactly this many (ignores the rules above)
    int fixed_point_iterations = 2;  // refinements of the backward warp per layer and sample
    // Output window in layer pixels; crop_w/crop_h = 0: the whole layer.
    int crop_x = 0, crop_y = 0, crop_w = 0, crop_h = 0;
};

struct ApertureRender {
    Image rgb;                // 3 channels, linear light, premultiplied by `alpha`
    Image alpha;              // 1 channel: coverage (1 wherever an opaque layer is behind)
    int samples = 0;          // aperture samples used
    double max_radius = 0.0;  // largest blur radius among the layers' visible pixels, px
};

// Renders layers given back to front (layers[0] farthest, usually an opaque background).
// Throws refocus::Error on empty input, mismatched sizes or channel counts, a bad lens or a
// crop window outside the layers.
ApertureRender render_aperture(const std::vector<ApertureLayer>& layers_back_to_front,
                               const ApertureLens& lens, const ApertureRenderOptions& opts = {});

// Largest A·|d − f| over the pixels of the layers with alpha > 0.
double max_blur_radius(const std::vector<ApertureLayer>& layers, const ApertureLens& lens);

// The sample count `render_aperture` uses for a largest blur radius `max_radius`.
int aperture_sample_count(double max_radius, const ApertureLens& lens,
                          const ApertureRenderOptions& opts = {});

// `count` points (u, v) uniformly covering the unit aperture shape of `lens` (zero mean).
std::vector<std::array<double, 2>> aperture_samples(const ApertureLens& lens, int count);

// Whether (u, v) lies inside the unit aperture shape of `lens`.
bool inside_aperture(const ApertureLens& lens, double u, double v);

}  // namespace refocus
