#pragma once
// The real-time preview on the GPU: the GLSL twin of engine/render/preview.h.
//   composite.frag  paper eq. 1 → C, B, (F, α)                        (one MRT draw)
//   dof_prep.frag   per layer: r (seed 001 eq. 1.12), highlight boost, 1/K(r)
//   dof_tiles.frag  per layer: largest radius reaching each 8×8 tile (early pass-through)
//   dof.frag        per layer: disk bokeh gather (paper eq. 2); the foreground pass composites
//                   over the blurred background: out = F̂ + (1 − Â)·B̂
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

#include "io/image.h"
#include "render/preview.h"

namespace refocus {

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
    // Or: layers already composited (3/3/1 channels); the next render() skips the composite.
    void set_layers(const PreviewLayers& layers);
    // Inverse depth per layer (empty image → the constant). Default: constants 0.
    void set_depth(const PreviewDepth& depth);

    // Runs the passes. aperture 0 after a composite pass: the result is the composite.
    void render(const PreviewLens& lens);

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
    void draw(unsigned int program, int w, int h, std::initializer_list<unsigned int> targets);
    Image read_texture(unsigned int tex, int w, int h, int channels) const;

    std::string m_dir;
    unsigned int m_composite_prog = 0, m_prep_prog = 0, m_tiles_prog = 0, m_dof_prog = 0;
    unsigned int m_vao = 0, m_fbo = 0;
    int m_width = 0, m_height = 0, m_tiles_w = 0, m_tiles_h = 0;
    // inputs
    unsigned int m_bg_atlas = 0, m_fg_atlas = 0, m_bg_uv = 0, m_fg_uv = 0, m_alpha = 0;
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
};

}  // namespace refocus
