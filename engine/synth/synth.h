#pragma once
// `refocus synth`: procedural misfocused clips with exact ground truth, rendered by the aperture
// renderer (render/aperture.h) — never by the lens blur layer the fit uses, so accuracy
// measured on them includes the fit's model error (occlusion at depth edges in particular).
//
// Every scene is two layers seen by a moving camera:
//   background: a slanted plane (a wall of posters: text-like glyphs at several sizes, checkers,
//     stripes, Siemens stars, coloured noise), its inverse depth affine in the image row,
//     d(y) = d_top + (d_bottom − d_top)·(y + 0.5)/H — exact for a plane tilted about the
//     horizontal axis (inverse depth of a plane is affine in image coordinates); in scene
//     "pillar" a full-height band of the same layer stands in front of it, nearer, so that the
//     layer's motion under a trucking camera is no homography (parallax within a layer);
//   foreground: a textured subject (head + torso) with a soft alpha edge, fronto-parallel at
//     one inverse depth per frame, its size proportional to that inverse depth (perspective).
// Camera: a horizontal translation (pan) that moves a point at inverse depth d by pan·d px
// (parallax between and within layers) plus a small handheld rotation, the same for all depths.
// Lens: thin lens, blur radius r = aperture·|d − focus| px (seed 001 eq. 1.12).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "io/image.h"
#include "render/aperture.h"

namespace refocus {

struct SynthSceneInfo {
    std::string name;
    std::string description;
};

// The scenes `refocus synth --scene NAME` knows: rack, walkout, pan, hunt, tripod, pillar.
const std::vector<SynthSceneInfo>& synth_scenes();

struct SynthOptions {
    std::string scene = "rack";
    int width = 320;
    int height = 180;
    int frames = 30;
    uint32_t seed = 1;
    double fps = 24.0;
    ApertureShape shape = ApertureShape::Circle;
    int blades = 6;
    double rotation_deg = 0.0;
};

// Camera, subject and lens of one frame (screen px, inverse depth).
struct SynthFrameState {
    double focus = 0.0;  // inverse depth in focus
    double fg_invdepth = 0.0;
    double fg_x = 0.0, fg_y = 0.0;  // subject centre before camera motion, px
    double pan = 0.0;  // camera translation: a point at inverse depth d moves pan·d px
    double shake_x = 0.0, shake_y = 0.0;  // camera rotation, px (depth-independent)
};

struct SynthFrame {
    Image input;     // misfocused, linear RGB (aperture renderer)
    Image sharp;     // all in focus, linear RGB
    Image coc;       // 1 channel: blur radius px of the visible surface (alpha ≥ 0.5: foreground)
    Image alpha;     // 1 channel: foreground alpha
    Image flow;      // 2 channels: forward flow t→t+1 of the visible surface, px (0 at the last)
    Image invdepth;  // 1 channel: inverse depth of the visible surface
    SynthFrameState state;
    int samples = 0;          // aperture samples used
    double max_radius = 0.0;  // largest blur radius in the frame, px
};

class SynthClip {
  public:
    // Throws refocus::Error for an unknown scene (listing the known ones) or a bad size.
    explicit SynthClip(const SynthOptions& opts);

    const SynthOptions& options() const { return m_opts; }
    int frames() const { return m_opts.frames; }
    double aperture() const { return m_aperture; }  // px per unit of inverse depth
    double bg_invdepth_top() const { return m_d_top; }
    double bg_invdepth_bottom() const { return m_d_bottom; }
    int margin() const { return m_margin; }  // layer margin beyond the frame, px

    SynthFrameState state(int t) const;
    ApertureLens lens(int t) const;
    // The two layers of frame t, back to front, with `margin()` px beyond the frame on each side.
    std::vector<ApertureLayer> layers(int t) const;
    SynthFrame render(int t) const;

    // clip.json: scene, size, frames, fps, seed, lens, radius formula, per-frame focus, ...
    std::string clip_json() const;

  private:
    double bg_invdepth(double y) const;  // y in screen px (the surface's own row)
    // Whether screen column x (px) sees the pillar of scene "pillar" in frame state st.
    bool on_pillar(double x, const SynthFrameState& st) const;
    // Scene "pillar": a full-height band in front of the wall, reference px and inverse depth.
    static constexpr double kPillarInvdepth = 0.8, kPillarU = 100.0, kPillarWidth = 26.0;
    SynthOptions m_opts;
    double m_scale = 1.0;  // H / 180: scene units are px of the 320x180 reference
    double m_aperture = 0.0;
    double m_d_top = 0.15, m_d_bottom = 0.55;
    int m_margin = 0;
};

// Writes the clip into `dir` (created if missing): input_%04d.png, sharp_%04d.png,
// coc_%04d.exr, alpha_%04d.png, flow_%04d.exr, clip.json. `progress(t)` after each frame.
// Returns the files written.
std::vector<std::string> write_synth_clip(const SynthOptions& opts, const std::string& dir,
                                          const std::function<void(int)>& progress = {});

// A COC map as a heat map (turbo colour map, 0 → dark blue, `max_radius` → dark red), linear
// RGB for writing through the sRGB encoder.
Image coc_heatmap(const Image& coc, double max_radius);

// input | sharp | heat-mapped COC side by side with `gap` px of white between.
Image synth_triplet(const SynthFrame& f, double max_radius, int gap = 4);

}  // namespace refocus
