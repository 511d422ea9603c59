#pragma once
// The representation a fit optimises (paper eq. 1): per-frame UV mappings into a background and
// a foreground atlas, an alpha matte, and the atlases. Two presets implement it: `fast`
// (explicit textures and warps, fast_model.h) and `paper` (MLP mappings + deep-image-prior CNN
// atlases). The engine (fit_engine.h) owns the data, the reblur and the reconstruction loss;
// models own their parameters and priors.
#include <torch/types.h>

#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "util/fs.h"
#include "ops/lens_blur.h"

namespace refocus {

// Everything the fit knows about the clip. Tensors are float32 on the CPU.
struct FitData {
    int frames = 0, height = 0, width = 0;
    torch::Tensor input;   // [T,3,H,W] linear light
    torch::Tensor radius;  // [T,H,W] circle-of-confusion radius, px, of the visible surface
    // Each layer's own radius with two layers (split_radius_by_layer, stack_coc.h): the subject's
    // beyond its silhouette, the wall's behind the subject. Undefined: `radius` for both.
    torch::Tensor radius_fg, radius_bg;  // [T,H,W]
    // The lens blur layer's kernel: the one the radii are measured in (the focal-stack estimate
    // matches blurs of this kernel; a given map is converted to it) and the reblur uses.
    LensBlurParams blur;
    torch::Tensor mask;        // [T,1,H,W] foreground in [0,1]; undefined: one layer
    torch::Tensor to_ref;      // [T,3,3] float64 homography frame t → reference frame
    torch::Tensor flow_fwd;    // [T-1,2,H,W] flow t → t+1, px (prepare/flow.h); may be undefined
    torch::Tensor flow_valid;  // [T-1,1,H,W] 1 where the flow is forward-backward consistent
    bool static_camera = true;
    bool has_subject = false;
    // Share of the wall (one layer: the frame) whose estimated radius holds over the clip: focus
    // never changed there, and the radius is the absolute floor (stack_coc.h). 0 with --coc.
    double fixed_focus_share = 0;
    // The clip's measured noise, σ in 8-bit sRGB levels averaged over the channels
    // (prepare/noise.h); < 0: not measured. The output rules test the residual against it.
    double noise_levels = -1;
    // The radius came as maps (`--coc`: an oracle or a depth-derived map), not the estimate.
    bool radius_given = false;
    // Atlas texels per frame pixel (choose_atlas_scale, fit_setup.h; a checkpoint keeps its own).
    double atlas_scale = 1;
    // The subject track a checkpoint was fitted with (checkpoint.cpp sets them from its
    // "subject_track"): "centroid" places the subject's atlas on its masks' centroids; "flow"
    // chains the flow over the masks as stored and steps over a frame without a mask by the
    // centroids; "flow-v2" (both false) cleans the masks along the track first.
    bool legacy_subject_track = false;
    bool legacy_track_gaps = false;
    torch::Tensor mask_as_stored;  // [T,1,H,W] the automatic masks before clean_subject_masks

    // Where clip-sized arrays live (util/mapped.h): empty, in memory; else in file mappings in
    // this folder (build_fit_data sets it for a clip whose frames exceed fit.memory_mb).
    fs::path mapped_dir;
    // A zero-filled float array for per-frame data ([T, ...]): mapped when mapped_dir is set.
    // With `keep` and a clip cache (below), the array is made in that cache's file of the name,
    // which keep_clip_array (model/clip_cache.h) then publishes.
    torch::Tensor clip_array(at::IntArrayRef shape, const char* keep = nullptr) const;
    // The input is known finite, the radius finite and non-negative (checked frame by frame as
    // they were made, or when they were kept, model/clip_cache.h): check_finite skips what is
    // known, so a long clip's arrays are not read again for it.
    bool input_finite = false, radius_finite = false;
    // subject_track's answers (model/atlas_geometry.h) for the masks and flow they were read
    // from (held, so that they are the same arrays, and their version: not written since), with
    // or without the scale, and the track's legacy flags; keep_clip stores the fit's own with
    // the kept arrays.
    struct TrackMemo {
        torch::Tensor mask, flow;
        bool scaled = false, legacy = false, gaps = false;
        std::pair<int64_t, int64_t> versions;
        std::vector<double> vx, vy, scale;
    };
    mutable std::vector<TrackMemo> track_memo;
    // The clip's arrays kept between commands (model/clip_cache.h): the folder and the key of
    // the data they were made from; empty: none kept.
    fs::path cache_dir;
    std::string cache_key;
    // clip_array's files not yet published: name → (file, its array, held so that no other
    // array takes its address).
    mutable std::map<std::string, std::pair<fs::path, torch::Tensor>> cache_pending;
    // fn(t) of every frame stacked into a clip array, [T, fn(0)'s sizes], one frame at a time.
    torch::Tensor per_frame(const std::function<torch::Tensor(int64_t)>& fn) const;

    const torch::Tensor& layer_radius(bool foreground) const {
        const torch::Tensor& r = foreground ? radius_fg : radius_bg;
        return r.defined() ? r : radius;
    }
};

// Throws unless every input frame is finite and every radius finite and non-negative (frame by
// frame: a long clip's arrays are file mappings, util/mapped.h).
// Throws unless the input is finite and the radius finite and non-negative (what d's flags say
// is known is not read again).
void check_finite(const FitData& d);
// One frame's check, for the flags above: finite; finite and non-negative.
bool finite_frame(const torch::Tensor& x);
bool finite_radius(const torch::Tensor& r);

// One rendered batch of frames. All [B,...].
struct Layers {
    torch::Tensor sharp;  // [B,3,H,W]  α·F + (1−α)·B   (paper eq. 1)
    torch::Tensor bg;     // [B,3,H,W]  A_b(M_b(p))
    torch::Tensor fg;     // [B,3,H,W]  A_f(M_f(p)), undefined with one layer
    torch::Tensor alpha;  // [B,1,H,W]  undefined with one layer
    torch::Tensor uv_bg;  // [B,H,W,2]  atlas coordinates in [-1,1] (grid_sample convention)
    torch::Tensor uv_fg;  // [B,H,W,2]  undefined with one layer
    // Frame pixel of each frame's layer pixel (0, 0): (−pad, −pad) for render_padded, the
    // window's corner for render_window. Empty: (0, 0) for every frame.
    std::vector<int64_t> x0, y0;
};

using LossTerms = std::map<std::string, double>;

struct ParamGroup {
    std::vector<torch::Tensor> params;
    double lr = 1e-3;
};

// Throws naming `who` unless there is one window corner per frame and every h × w window lies
// within `pad` px of the height × width frame.
void check_windows(const std::string& who, int64_t frames, int64_t height, int64_t width,
                   int64_t pad, const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                   int64_t h, int64_t w);

class FitModel {
  public:
    virtual ~FitModel() = default;
    std::vector<std::string> notes;  // what the model decided at construction, for the log
    virtual std::string preset() const = 0;
    virtual std::vector<ParamGroup> param_groups() = 0;
    virtual Layers render(const std::vector<int64_t>& frames) = 0;
    // Frames rendered with `pad` px of scene beyond every edge ([B,·,H+2·pad,W+2·pad]). The
    // input was shot through a lens that saw past the frame: a pixel near the edge holds light
    // from outside it, so the reblur of paper eq. 3 is computed on the padded frame and cropped
    // (the engine does this in training). Models that cannot extrapolate their mapping return
    // 0 from max_pad().
    virtual int64_t max_pad() const { return 0; }
    // Frames per step when the user gave none (FitOptions::batch 0).
    virtual int preferred_batch() const { return 2; }
    virtual std::string preferred_batch_reason() const { return {}; }
    virtual Layers render_padded(const std::vector<int64_t>& frames, int64_t pad);
    // Frames rendered over windows of h × w px, frame b's over frame pixels [x0[b], x0[b] + w)
    // × [y0[b], y0[b] + h), each within max_pad() px of the frame: [B,·,h,w]. The fit's crop
    // step renders a crop plus the blur's margin (docs/method.md, Crops). The default cuts the
    // windows out of render_padded (exact, not cheaper); the fast model samples its atlases at
    // the window's pixels only.
    virtual Layers render_window(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                                 const std::vector<int64_t>& y0, int64_t h, int64_t w);
    // Priors of paper eq. 4 that the model owns (sparsity, rigidity, flow, TV, mask bootstrap),
    // weighted, summed; each term's value is recorded in `terms`.
    virtual torch::Tensor priors(const Layers& layers, const std::vector<int64_t>& frames,
                                 int64_t step, LossTerms& terms) = 0;
    // The atlases as images for display, export and editing: [3,Ha,Wa] (fg undefined with one
    // layer). set_* replaces the atlas content (imported repaint) keeping the mapping.
    virtual torch::Tensor atlas_bg() = 0;
    virtual torch::Tensor atlas_fg() = 0;
    // The background's parallax field over its atlas, [1,H,W] (undefined: the model has none).
    virtual torch::Tensor parallax_bg() { return {}; }
    virtual void set_atlas_bg(const torch::Tensor& rgb) = 0;
    virtual void set_atlas_fg(const torch::Tensor& rgb) = 0;
    // A model that is not trained by gradient steps on the reconstruction loss (perframe, which
    // deconvolves one frame a step) steps itself: the engine calls step_itself(step) instead,
    // the fit ends after step_count() steps, and frame_done(t) says which frames it reached.
    // `commit` guards the model's tensors while the UI renders: lock it only to write them.
    virtual bool steps_itself() const { return false; }
    virtual void step_itself(int64_t step, std::mutex& commit) {}
    virtual int64_t step_count() const { return -1; }  // -1: the budget decides
    virtual bool frame_done(int t) const { return true; }
    // Named tensors that fully determine the model (for checkpoints).
    virtual std::map<std::string, torch::Tensor> state() = 0;
    // Copies `s` into the tensors of state(), checking that every name is there with the
    // shape the model expects (a checkpoint of another clip or preset is refused by name).
    virtual void load_state(const std::map<std::string, torch::Tensor>& s);
};

}  // namespace refocus
