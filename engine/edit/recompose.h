#pragma once
// The refocused frame: the fit's own sampled layers of frame t (paper eq. 1) through the preview's
// CPU twin (render/preview.h: layered disk-bokeh depth of field) with the inverse depth of
// edit/depth.h and a lens from edit/focus.h. Used by `refocus export --what refocus`.
#include "edit/depth.h"
#include "model/fit_model.h"
#include "io/image.h"
#include "render/preview.h"

namespace refocus {

class FitEngine;

// Frame t's maps as images (all the frame's size): sharp 3, bg 3, fg 3, alpha 1, uv_bg 2, uv_fg 2
// channels; fg, alpha and uv_fg are empty for a one-layer clip.
// bg_fix / fg_fix (3 channels; empty: none): what the exported plate adds to each layer over
// the layer the atlases give (the output rules and the low-frequency lock, FitEngine::
// apply_fallback), for a preview that samples the atlases itself (render/preview.h,
// composite_layers) to show what export writes.
struct FrameMaps {
    Image sharp, bg, fg, alpha, uv_bg, uv_fg;
    Image bg_fix, fg_fix;
};

// Renders frame t (the engine locks its model for the render; no gradients).
FrameMaps frame_maps(FitEngine& engine, int t);
// The same with atlas edits (AtlasEditor::delta, [1,3,Ha,Wa]; undefined: none) drawn in, as the
// export draws them (edit/atlas_edit.h apply_edits, then the fallback to the shot).
FrameMaps frame_maps(FitEngine& engine, int t, const torch::Tensor& bg_delta,
                     const torch::Tensor& fg_delta);
// The first frame of a rendered batch (e.g. after edit/atlas_edit.h apply_edits).
FrameMaps frame_maps(const Layers& layers);

// Frame t's confidence (channel 0, FitEngine::confidence: 1 where the fit explains the pixel)
// and the fit's share of the sharp plate (channel 1, FitEngine::model_weight: 0 where the plate
// is the shot), as a 2-channel image of the frame's size.
Image confidence_image(const FitEngine& engine, int t);

// The frame's layers as the depth-of-field pass takes them (one layer: an empty foreground).
PreviewLayers preview_layers(const FrameMaps& m);
// render_dof of m's layers with depth.frame_depth(t, ...) and `lens`. Aperture 0 gives the sharp
// composite α·F + (1 − α)·B.
Image render_refocused(const FrameMaps& m, const DepthModel& depth, int t, const PreviewLens& lens,
                       int threads = 1);

}  // namespace refocus
