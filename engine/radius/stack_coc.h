#pragma once
// Blur radius from the clip itself used as a focal stack ("depth from defocus"): when focus
// changes over a shot, every region is seen at several blur levels. An all-in-focus (AIF)
// composite is built in reference coordinates from the locally sharpest frames, mapped back
// into each frame, and the radius at each pixel is the r whose lens-blurred AIF best matches
// the frame locally:   r_t(x) = argmin_r  Σ_{window(x)} ‖L(AIF_t, r) − I_t‖²,
// with L the fit's own blur layer (paper eq. 2), so the estimate is in the units the fit needs.
// Where the frame is flat the cost does not depend on r; there the estimate is spread from
// confident neighbours with the confidence-weighted guided filter (prepare/coc.h).
// The single-image estimator (edge reblur ratio) reads dense texture far too low
// (docs/method.md, Radius estimation); this one needs focus to vary over the clip and a
// registration, which prepare provides.
// The stack alone is relative: the sharpest view of each point reads 0, so what a clip never
// shows in focus would be left as shot. The composite's own blur r0 is therefore measured at its
// edges (edge_blur.h, a single-image absolute estimate that only trusts isolated steps), spread
// over the layer, and combined with the relative radius: r_t = sqrt(r0² + r_rel,t²).
#include <torch/types.h>

#include <string>

#include "radius/edge_blur.h"
#include "radius/spectral_blur.h"
#include "model/fit_model.h"

namespace refocus {

struct StackCocOptions {
    double rmax = 14.0;  // largest radius tested (px)
    double rstep = 0.5;  // radius grid
    // The reference: each radius of the grid blurred directly (lens_blur), not by FFT
    // (ops/uniform_blur.h, the same kernel; it differs only within the kernel's reach of the
    // frame's border). Its cost grows with r².
    bool direct_blur = false;
    int window = 4;  // half-size of the matching window (px)
    int contrast_window = 3;
    double min_confidence = 1e-4;  // cost spread (max − min) below this: not measured here
    int spread_px = 6;  // window of the confidence-weighted spread (then H/10 for the rest)
    // The subject's pass over a box around it in each frame (off: over the whole frames, the
    // reference; they agree inside the subject's region, docs/method.md, Radius estimation).
    bool subject_boxes = true;
    // Set by the subject's pass over boxes (not settings): the frame's sizes its crops keep for
    // the wide spread's window and the floor's cells (0: the frame's and the canvas's own).
    int spread_far_px = 0;
    int64_t floor_cell_side = 0;
    double min_explained = 0.6;  // share of local variance the best match must explain to count
    // The composite's own (absolute) blur, measured at its edges (edge_blur.h) and added to the
    // stack's relative radius: r_t = sqrt(r0² + r_rel²) (second moments add). Off: relative only.
    bool absolute = true;
    EdgeBlurOptions edge;
    int min_edges = 20;            // fewer accepted edges in a layer's composite: no floor there
    int floor_frames = 30;         // frames whose edges and tiles are read (spread over the clip)
    int64_t floor_edges = 400000;  // edges tested over those frames in all (0: edge.max_candidates
                                   //   a frame): a 640 px proxy's 20 000 a frame are halved, a
                                   //   320 px clip's 8 000 kept
    int min_local_edges = 3;       // edges within the spread window a pixel's floor averages
    int floor_fill_cells = 4;    // empty floor cells take their measured neighbours' up to this far
    double floor_rel_max = 1.0;  // edges count where the frame is within this of its sharpest view
    double floor_gate_lo = 1.5;  // the floor applies where no frame sees the point blurrier than
    double floor_gate_hi = 2.5;  //   its sharpest view by gate_lo, and not past gate_hi
    double floor_gate_rel_lo = 0.4;  // ... and not under these shares of the floor itself
    double floor_gate_rel_hi = 0.6;
    double floor_gate_quantile_spectral = 0.75;  // under a floor from tile spectra the gate reads
                                                 //   this quantile of the views, not their largest
    int floor_gate_clear_px = 12;  // the gate reads only views this far inside the layer's region
                                   //   (where a point has such views): the other layer's rim
    double spectral_from = 3.5;    // a layer whose edges' floor reads more is read from tile
                                 //   spectra (spectral_blur.h), whose floor is taken past floor_max
    double floor_max = 4.5;  // ... else the edges' up to this, past it none
    bool spectral = true;    // off: such a layer keeps no floor
    SpectralBlurOptions spectral_blur;
    int min_tiles = 20;      // fewer tiles read: no floor
    double floor_lo = 0.75;  // r0 under floor_lo reads 0, from floor_lo to floor_hi it ramps
    double floor_hi = 1.5;   //   up to r0 (a sharp composite's edges read 0-0.75 px)
};

// What the estimate found, for the log.
struct StackCocReport {
    std::string summary;  // e.g. "absolute floor: wall 851 edges (median 1.25 px), subject ..."
    double fixed_focus_share =
        0;  // the wall's (one layer: the frame's) share with the floor applied
};

// Warp [N,C,h,w] images onto an H x W grid: output pixel p reads the source at m·p (m [3,3]
// float64; bicubic, border padding; `zeros`: bilinear and 0 outside, for validity maps). A
// whole-pixel translation is a shifted copy (`shifts_as_copies` off: the sampler, the reference).
torch::Tensor warp_to_canvas(const torch::Tensor& src, const torch::Tensor& m, int64_t H, int64_t W,
                             bool zeros = false, bool shifts_as_copies = true);

// [T,H,W] radius maps for d.input registered by d.to_ref. Needs at least 2 frames.
torch::Tensor estimate_radius_from_stack(const FitData& d, const StackCocOptions& opts = {},
                                         StackCocReport* report = nullptr);

// Each layer's own radius (FitData::radius_fg / radius_bg) from the visible surface's map
// `d.radius` and the masks. The map holds the subject's radius inside its silhouette and the
// wall's outside; the lens blur layer scatters every source pixel over its own radius, so the
// subject's α·F and α must spread with the subject's radius beyond its edge, and the wall
// behind the subject's edge (seen through a blurred edge, paper eq. 3 layered) with the
// wall's. Each layer keeps the map where its mask is sure (eroded by `margin` px, so that a
// mask a little off the true silhouette does not hand one layer the other's radius) and is
// filled elsewhere from there (push-pull). One layer (no mask): left undefined.
void split_radius_by_layer(FitData& d, int margin = 2);

}  // namespace refocus
