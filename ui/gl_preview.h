#pragma once
// The real-time preview on the GPU: the GLSL twin of engine/render/preview.h.
//   composite.frag  paper eq. 1 → C, B, (F, α)                        (one MRT draw)
//   dof_prep.frag   per layer: r (seed 001 eq. 1.12), highlight boost, 1/K(r)
//   dof_tiles.frag  per layer: largest radius reaching each 8×8 tile (early pass-through)
//   dof.frag        per layer: disk bokeh gather (paper eq. 2); the foreground pass composites
//                   over the blurred background: out = F̂ + (1 − Â)·B̂
// That is PreviewQuality::Exact, equal to the CPU twin to float rounding. PreviewQuality::Fast
// (gl_preview_fast.cpp; GPU only, no CPU twin) keeps composite and prep and replaces the tiles
// and the gather with the passes real-time engines use, an approximation of the exact result:
//   dof_fast_tiles   max radius (and foreground α) per 16×16 tile, both layers
//   dof_fast_dilate  … grown to what can reach each tile; R < ½: early pass-through
//   dof_fast_down    half-resolution sources, highlights split off
//   dof_fast_gather  per layer, half resolution: N-sample disk sums for tiles with R > 1.5 px
//   dof_sprite       per layer: highlights as additive disk sprites, only where they are
//   dof_fast         full resolution, per layer, one draw per tile class over its tiles only:
//                    exact gather where R ≤ 1.5 px, else own term + upsampled sums + sprites;
//                    the foreground's draws write out = F̂ + (1 − Â)·B̂
// Works in a GL 3.3 core context (the studio's GLFW window) and headless on OSMesa (tests, the
// benchmark). Needs a current context for its whole life; touches no GL state it does not put
// back (framebuffer, viewport, program, vertex array, blend/depth/scissor enables).
//
// Linking: this library calls the gl* entry points directly (GL_GLEXT_PROTOTYPES) and links no
// GL library itself — the studio links libGL, the OSMesa tools libOSMesa — and it uses the CPU
// twin's tables (preview_shape_table, preview_area_table), which come from refocus_engine (the
// studio) or refocus_preview_cpu (torch-free tools).
//
// Typical studio use, on the UI thread:
//   GlPreview gp;                                      // after the context is current
//   gp.set_atlases(bg_atlas, fg_atlas);                // when the atlas version changes
//   gp.set_frame(bg_uv, fg_uv, alpha);  gp.set_depth(depth);   // when the frame changes
//   gp.render(lens);                                   // every change of lens or frame
//   ImGui::Image((ImTextureID)(intptr_t)gp.result_texture(), ...);
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include "io/image.h"
#include "render/preview.h"

namespace refocus {

// Exact: the reference gather (every source within reach, equal to the CPU twin). Fast: the
// real-time approximation for playback and scrubbing (docs/method.md, "The preview's depth of
// field"); tests/gl/test_gl_preview.cpp bounds its error against Exact.
enum class PreviewQuality { Exact, Fast };

// Radii the fast path gathers exactly at full resolution (tiles whose dilated radius is at most
// this), px; larger tiles are gathered at half resolution.
constexpr float kFastSmallRadius = 1.5f;
constexpr int kFastTileSize = 16;  // px per side of the fast path's tiles
// Most samples (≤ 64) per half-resolution pixel of the fast path's disk gather.
constexpr int kFastSamples = 20;

class GlPreview {
  public:
    // Compiles the passes from `shader_dir` (default: the source tree's shaders/, set at build
    // time through SHADER_SOURCE_DIR). Throws refocus::Error naming the file and the GL log.
    explicit GlPreview(const std::string& shader_dir = default_shader_dir());
    ~GlPreview();
    GlPreview(const GlPreview&) = delete;
    GlPreview& operator=(const GlPreview&) = delete;

    static std::string default_shader_dir();

    // Atlases, ≥ 3 channels (extra ignored); `foreground_atlas` may be empty (one layer).
    void set_atlases(const Image& background_atlas, const Image& foreground_atlas);
    // This frame's UV maps (2 channels) and alpha (1 channel), all the frame's size; the next
    // render() runs the composite pass. foreground_uv/alpha are ignored without a foreground
    // atlas, so call set_atlases() first.
    void set_frame(const Image& background_uv, const Image& foreground_uv, const Image& alpha);
    // What the exported plate adds to each layer (composite_layers' fixes, preview.h); empty
    // images: none. Call after set_frame, which clears it.
    void set_frame_fix(const Image& background_fix, const Image& foreground_fix);
    // Or: layers already composited (3/3/1 channels); the next render() skips the composite.
    void set_layers(const PreviewLayers& layers);
    // Inverse depth per layer (empty image → the constant). Default: constants 0.
    void set_depth(const PreviewDepth& depth);

    // Runs the passes. aperture 0 after a composite pass: the result is the composite.
    void render(const PreviewLens& lens, PreviewQuality quality = PreviewQuality::Exact);

    // With timing on, render() waits for the GPU after each stage and records its time (ms) in
    // pass_times() (the benchmark's per-pass figures; off in the studio: glFinish stalls).
    void set_timing(bool on) { m_timing = on; }
    const std::vector<std::pair<std::string, double>>& pass_times() const { return m_pass_times; }

    int width() const { return m_width; }
    int height() const { return m_height; }
    // RGBA32F textures, frame size, texel row 0 = image row 0 (the top): ImGui::Image with the
    // default uv0 = (0, 0), uv1 = (1, 1) shows them upright.
    unsigned int composite_texture() const { return m_composite; }  // (C, 1)
    unsigned int result_texture() const;                            // (depth of field, 1)

    // Read-backs (glReadPixels; they wait for the GPU).
    Image read_composite() const;  // 3 channels
    PreviewLayers read_layers() const;
    Image read_result() const;  // 3 channels

  private:
    void ensure_size(int w, int h);
    void ensure_tables(const PreviewLens& lens);
    void render_exact(const PreviewLens& lens);
    // gl_preview_fast.cpp
    void render_fast(const PreviewLens& lens);
    void ensure_fast(int w, int h);
    void fast_sources(const PreviewLens& lens);
    void fast_gather(const PreviewLens& lens);
    void fast_resolve(const PreviewLens& lens);
    void lens_uniforms(unsigned int prog, const PreviewLens& lens);
    void mark_pass(const char* name);
    // A fullscreen triangle, or `count` vertices of `primitive` (the sprites' points, the tile
    // classes' quads), into `targets` (≤ 8); count < 0 binds the targets and the viewport only.
    void draw(unsigned int program, int w, int h, std::initializer_list<unsigned int> targets,
              int count = 0, unsigned int primitive = 0 /* GL_POINTS */);
    Image read_texture(unsigned int tex, int w, int h, int channels) const;

    std::string m_dir;
    unsigned int m_composite_prog = 0, m_prep_prog = 0, m_tiles_prog = 0, m_dof_prog = 0;
    unsigned int m_vao = 0, m_fbo = 0;
    int m_width = 0, m_height = 0, m_tiles_w = 0, m_tiles_h = 0;
    // inputs
    unsigned int m_bg_atlas = 0, m_fg_atlas = 0, m_bg_uv = 0, m_fg_uv = 0, m_alpha = 0;
    unsigned int m_bg_fix = 0, m_fg_fix = 0;
    bool m_has_fix = false;
    unsigned int m_bg_depth = 0, m_fg_depth = 0;
    bool m_has_fg_atlas = false, m_has_bg_depth = false, m_has_fg_depth = false;
    bool m_fg_frame = false;  // foreground UV and alpha uploaded for the current atlases
    int m_bg_depth_w = 0, m_bg_depth_h = 0, m_fg_depth_w = 0, m_fg_depth_h = 0;
    float m_bg_depth_const = 0.0f, m_fg_depth_const = 0.0f;
    bool m_need_composite = false, m_composited = false;
    // layers: (C, 1), (B, 1), (F, α)
    unsigned int m_composite = 0, m_background = 0, m_foreground = 0;
    // depth of field: per layer [0] background, [1] foreground
    unsigned int m_prep0[2] = {0, 0}, m_prep1[2] = {0, 0}, m_tiles[2] = {0, 0};
    unsigned int m_blurred_bg = 0, m_result = 0;
    bool m_result_is_composite = false;
    // tables, rebuilt when the kernel's shape changes
    unsigned int m_shape_tx = 0, m_area_tx = 0;
    int m_window = -1;
    double m_table_beta = -1.0, m_table_rotation = 0.0, m_table_max_radius = -1.0;
    int m_table_blades = -1;
    float m_area_fit[3] = {0.0f, 0.0f, 0.5f};  // K(r) ≈ c2·r² + c1·r + c0 (fast path)
    // fast path: programs, tiles, half-resolution sources and sums, sprite sums
    unsigned int m_fast_tiles_prog = 0, m_fast_dilate_prog = 0, m_fast_down_prog = 0;
    unsigned int m_fast_gather_prog = 0, m_sprite_prog = 0;
    unsigned int m_fast_prog[2][3] = {{0, 0, 0}, {0, 0, 0}};  // [layer][tile class]
    int m_fast_w = 0, m_fast_h = 0, m_half_w = 0, m_half_h = 0, m_fast_tiles_w = 0,
        m_fast_tiles_h = 0;
    unsigned int m_fast_tiles = 0, m_fast_dilated = 0;
    unsigned int m_half_bg = 0, m_half_fg = 0, m_half_alpha = 0, m_half_sprite[2] = {0, 0};
    unsigned int m_half_spot[2] = {0, 0};
    unsigned int m_half_sum[2] = {0, 0}, m_half_weight[2] = {0, 0}, m_sprite_sum[2] = {0, 0};
    // timing
    bool m_timing = false;
    double m_pass_t0 = 0.0;
    std::vector<std::pair<std::string, double>> m_pass_times;
};

}  // namespace refocus
