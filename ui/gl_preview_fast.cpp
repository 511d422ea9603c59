// The fast depth-of-field path of GlPreview (PreviewQuality::Fast); see gl_preview.h for the
// passes and shaders/dof_fast*.frag for the equations. GPU only: its reference is the exact
// path, and tests/gl/test_gl_preview.cpp bounds the difference.
#include <GL/gl.h>
#include <GL/glext.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "gl_preview.h"
#include "gl_preview_util.h"

namespace refocus {

namespace gl_util {

void fit_area_table(const std::vector<float>& area, int steps, float out[3]) {
    // Normal equations of Σ ((c2·r² + c1·r + c0 − K)/K)² over the entries with r ≥ 2 (the
    // gather's sources that matter; below, K steps with the pixel grid and no quadratic fits).
    double m[3][4] = {};
    for (size_t i = static_cast<size_t>(2 * steps); i < area.size(); ++i) {
        const double r = static_cast<double>(i) / steps, k = area[i];
        if (!(k > 0.0)) continue;
        const double b[3] = {r * r / k, r / k, 1.0 / k};
        for (int a = 0; a < 3; ++a) {
            for (int c = 0; c < 3; ++c) m[a][c] += b[a] * b[c];
            m[a][3] += b[a];
        }
    }
    if (m[2][2] < 3.0) {  // radii below 2 px only: π·r² + ½ stands in
        out[0] = static_cast<float>(M_PI);
        out[1] = 0.0f;
        out[2] = 0.5f;
        return;
    }
    for (int c = 0; c < 3; ++c)  // Gauss-Jordan; the system is small and well conditioned
        for (int r = 0; r < 3; ++r) {
            if (r == c) continue;
            const double f = m[r][c] / m[c][c];
            for (int k = c; k < 4; ++k) m[r][k] -= f * m[c][k];
        }
    for (int a = 0; a < 3; ++a) out[a] = static_cast<float>(m[a][3] / m[a][a]);
}

}  // namespace gl_util

using namespace gl_util;

namespace {

const double kGoldenAngle = M_PI * (3.0 - std::sqrt(5.0));  // radians: the spiral's even spread
const double kSpriteMinRadius = 0.5;  // a blurred highlight is a sprite; r ≤ ½ is sharp

// A source brighter than display white (or the lens's threshold, if higher) is a highlight.
double highlight_level(const PreviewLens& lens) {
    return std::max(lens.highlight_threshold, 1.0);
}

}  // namespace

void GlPreview::lens_uniforms(unsigned int prog, const PreviewLens& lens) {
    set_float(prog, "u_beta", lens.beta);
    set_int(prog, "u_blades", lens.blades);
    if (lens.blades >= 3) {  // edge normals at rotation + π/n + 2πk/n, over cos(π/n)
        std::vector<float> m(2 * lens.blades);
        const double rot = lens.rotation_deg * M_PI / 180.0, n = lens.blades;
        for (int k = 0; k < lens.blades; ++k) {
            const double a = rot + M_PI / n + 2.0 * M_PI * k / n;
            m[2 * k] = static_cast<float>(std::cos(a) / std::cos(M_PI / n));
            m[2 * k + 1] = static_cast<float>(std::sin(a) / std::cos(M_PI / n));
        }
        glUniform2fv(glGetUniformLocation(prog, "u_edge_normals"), lens.blades, m.data());
    }
    glUniform3f(glGetUniformLocation(prog, "u_area_fit"), m_area_fit[0], m_area_fit[1],
                m_area_fit[2]);
    glUniform2f(glGetUniformLocation(prog, "u_full_size"), static_cast<float>(m_width),
                static_cast<float>(m_height));
}

void GlPreview::ensure_fast(int w, int h) {
    if (!m_fast_tiles_prog) {
        m_fast_tiles_prog = link_program(m_dir, "dof_fast_tiles.frag");
        m_fast_dilate_prog = link_program(m_dir, "dof_fast_dilate.frag");
        m_fast_down_prog = link_program(m_dir, "dof_fast_down.frag");
        m_fast_gather_prog = link_program(m_dir, "dof_fast_gather.frag");
        m_sprite_prog = link_program(m_dir, "dof_sprite.frag", "dof_sprite.vert");
        // The background has no class 0 (no colour): it always has its own.
        for (int layer = 0; layer < 2; ++layer)
            for (int cls = 1 - layer; cls < 3; ++cls)
                m_fast_prog[layer][cls] =
                    link_program(m_dir, "dof_fast.frag", "dof_fast_class.vert",
                                 "#define FAST_FOREGROUND " + std::to_string(layer) +
                                     "\n#define FAST_CLASS " + std::to_string(cls) + "\n");
    }
    if (w == m_fast_w && h == m_fast_h) return;
    m_fast_w = w;
    m_fast_h = h;
    m_half_w = (w + 1) / 2;
    m_half_h = (h + 1) / 2;
    m_fast_tiles_w = (w + kFastTileSize - 1) / kFastTileSize;
    m_fast_tiles_h = (h + kFastTileSize - 1) / kFastTileSize;
    for (GLuint* t : {&m_fast_tiles, &m_fast_dilated})
        allocate(*t, GL_RGBA32F, m_fast_tiles_w, m_fast_tiles_h, GL_RGBA, nullptr);
    // Bilinear: the resolve upsamples the sums and reads the sources' neighbourhood.
    for (GLuint* t : {&m_half_bg, &m_half_fg, &m_half_sum[0], &m_half_sum[1]})
        allocate(*t, GL_RGBA32F, m_half_w, m_half_h, GL_RGBA, nullptr, true);
    for (GLuint* t : {&m_half_alpha, &m_half_weight[0], &m_half_weight[1]})
        allocate(*t, GL_R32F, m_half_w, m_half_h, GL_RED, nullptr, true);
    for (GLuint* t : {&m_half_sprite[0], &m_half_sprite[1]})
        allocate(*t, GL_RGBA32F, m_half_w, m_half_h, GL_RGBA, nullptr);
    for (GLuint* t : {&m_half_spot[0], &m_half_spot[1]})
        allocate(*t, GL_RG32F, m_half_w, m_half_h, GL_RG, nullptr);
    for (GLuint* t : {&m_sprite_sum[0], &m_sprite_sum[1]})
        allocate(*t, GL_RGBA32F, w, h, GL_RGBA, nullptr);
}

void GlPreview::render_fast(const PreviewLens& lens) {
    ensure_fast(m_width, m_height);
    fast_sources(lens);
    fast_gather(lens);
    fast_resolve(lens);
}

// Tiles, their dilation, and the half-resolution sources (dof_fast_tiles, _dilate, _down).
void GlPreview::fast_sources(const PreviewLens& lens) {
    GLuint prog = m_fast_tiles_prog;
    glUseProgram(prog);
    bind_sampler(prog, "u_bg_prep0_tx", 0, m_prep0[0]);
    bind_sampler(prog, "u_fg_prep0_tx", 1, m_prep0[1]);
    bind_sampler(prog, "u_fg_prep1_tx", 2, m_prep1[1]);
    set_int(prog, "u_tile_size", kFastTileSize);
    draw(prog, m_fast_tiles_w, m_fast_tiles_h, {m_fast_tiles});

    prog = m_fast_dilate_prog;
    glUseProgram(prog);
    bind_sampler(prog, "u_tiles_tx", 0, m_fast_tiles);
    set_int(prog, "u_tile_size", kFastTileSize);
    // A tile s can reach t only when its gap (|Δt| − 1)·T + 1 < max_radius + ½.
    set_int(prog, "u_reach",
            static_cast<int>(std::ceil((lens.max_radius + 0.5 - 1.0) / kFastTileSize)) + 1);
    draw(prog, m_fast_tiles_w, m_fast_tiles_h, {m_fast_dilated});
    mark_pass("fast tiles");

    prog = m_fast_down_prog;
    glUseProgram(prog);
    bind_sampler(prog, "u_bg_prep0_tx", 0, m_prep0[0]);
    bind_sampler(prog, "u_fg_prep0_tx", 1, m_prep0[1]);
    bind_sampler(prog, "u_fg_prep1_tx", 2, m_prep1[1]);
    set_float(prog, "u_highlight_level", highlight_level(lens));
    set_float(prog, "u_sprite_min_radius", kSpriteMinRadius);
    draw(prog, m_half_w, m_half_h,
         {m_half_bg, m_half_fg, m_half_alpha, m_half_sprite[0], m_half_sprite[1], m_half_spot[0],
          m_half_spot[1]});
    mark_pass("half-res sources");
}

// The half-resolution disk sums and the highlight sprites (dof_fast_gather, dof_sprite).
void GlPreview::fast_gather(const PreviewLens& lens) {
    GLuint prog = m_fast_gather_prog;
    glUseProgram(prog);
    lens_uniforms(prog, lens);
    set_int(prog, "u_tile_size", kFastTileSize);
    set_float(prog, "u_small_radius", kFastSmallRadius);
    set_int(prog, "u_samples", kFastSamples);
    {
        float dirs[2 * kFastSamples];
        for (int i = 0; i < kFastSamples; ++i) {
            const double a = i * kGoldenAngle;
            dirs[2 * i] = static_cast<float>(std::cos(a));
            dirs[2 * i + 1] = static_cast<float>(std::sin(a));
        }
        glUniform2fv(glGetUniformLocation(prog, "u_spiral"), kFastSamples, dirs);
    }
    for (int layer = 0; layer < 2; ++layer) {
        bind_sampler(prog, "u_src_tx", 0, layer ? m_half_fg : m_half_bg);
        bind_sampler(prog, "u_alpha_tx", 1, m_half_alpha);
        bind_sampler(prog, "u_tiles_tx", 2, m_fast_dilated);
        set_int(prog, "u_foreground", layer);
        draw(prog, m_half_w, m_half_h, {m_half_sum[layer], m_half_weight[layer]});
    }
    mark_pass("half-res gather");

    prog = m_sprite_prog;
    glUseProgram(prog);
    lens_uniforms(prog, lens);
    glEnable(GL_PROGRAM_POINT_SIZE);
    glBlendFuncSeparate(GL_ONE, GL_ONE, GL_ONE, GL_ONE);
    glBlendEquationSeparate(GL_FUNC_ADD, GL_FUNC_ADD);
    const float zero[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (int layer = 0; layer < 2; ++layer) {
        bind_sampler(prog, "u_sprite_tx", 0, m_half_sprite[layer]);
        bind_sampler(prog, "u_area_tx", 1, m_area_tx);
        bind_sampler(prog, "u_spot_tx", 2, m_half_spot[layer]);
        set_int(prog, "u_area_steps", kPreviewAreaSteps);
        glDisable(GL_BLEND);
        draw(prog, m_width, m_height, {m_sprite_sum[layer]}, -1);
        glClearBufferfv(GL_COLOR, 0, zero);
        glEnable(GL_BLEND);
        draw(prog, m_width, m_height, {m_sprite_sum[layer]},
             ((m_half_w + 1) / 2) * ((m_half_h + 1) / 2), GL_POINTS);
    }
    glDisable(GL_BLEND);
    glDisable(GL_PROGRAM_POINT_SIZE);
    mark_pass("highlight sprites");
}

// Full resolution, per layer and tile class, each class drawn over its own tiles (dof_fast.frag,
// dof_fast_class.vert): the background into m_blurred_bg, then the foreground over it.
void GlPreview::fast_resolve(const PreviewLens& lens) {
    const int quads = 6 * m_fast_tiles_w * m_fast_tiles_h;
    for (int layer = 0; layer < 2; ++layer)
        for (int cls = 1 - layer; cls < 3; ++cls) {
            const GLuint prog = m_fast_prog[layer][cls];
            glUseProgram(prog);
            bind_sampler(prog, "u_prep0_tx", 0, m_prep0[layer]);
            bind_sampler(prog, "u_prep1_tx", 1, m_prep1[layer]);
            bind_sampler(prog, "u_tiles_tx", 2, m_fast_dilated);
            bind_sampler(prog, "u_shape_tx", 3, m_shape_tx);
            bind_sampler(prog, "u_sum_tx", 4, m_half_sum[layer]);
            bind_sampler(prog, "u_weight_tx", 5, m_half_weight[layer]);
            bind_sampler(prog, "u_sprite_tx", 6, m_sprite_sum[layer]);
            bind_sampler(prog, "u_src_tx", 7, layer ? m_half_fg : m_half_bg);
            bind_sampler(prog, "u_alpha_tx", 8, m_half_alpha);
            // The background's draws must not sample their own target: the composite (unused).
            bind_sampler(prog, "u_background_tx", 9, layer ? m_blurred_bg : m_composite);
            set_int(prog, "u_tile_size", kFastTileSize);
            set_int(prog, "u_foreground", layer);
            set_int(prog, "u_class", cls);
            set_float(prog, "u_small_radius", kFastSmallRadius);
            glUniform2f(glGetUniformLocation(prog, "u_full_size"), static_cast<float>(m_width),
                        static_cast<float>(m_height));
            set_int(prog, "u_window", m_window);
            set_float(prog, "u_beta", lens.beta);
            set_int(prog, "u_samples", kFastSamples);
            set_float(prog, "u_highlight_level", highlight_level(lens));
            set_float(prog, "u_sprite_min_radius", kSpriteMinRadius);
            draw(prog, m_width, m_height, {layer ? m_result : m_blurred_bg}, quads, GL_TRIANGLES);
        }
    mark_pass("resolve");
}

}  // namespace refocus
