// The real-time preview on the GPU; see gl_preview.h. The equations live in the shaders'
// headers and in engine/render/preview.h.
#include "gl_preview.h"

#include <GL/gl.h>
#include <GL/glext.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <sstream>
#include <vector>

#include "gl_preview_util.h"
#include "util/error.h"

#ifndef SHADER_SOURCE_DIR
#define SHADER_SOURCE_DIR "shaders"
#endif

namespace refocus {

namespace {

double now_ms() {
    using namespace std::chrono;
    return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

std::string read_text(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(file_error(path, "cannot open shader source"));
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

// Splices `#include "name"` lines (resolved in `dir`); GLSL itself has no include. `defines`
// (lines such as "#define X 1\n") go after the #version line: one source, several variants.
std::string load_source(const std::string& dir, const std::string& name,
                        const std::string& defines) {
    std::istringstream in(read_text(dir + "/" + name));
    std::string line, out;
    while (std::getline(in, line)) {
        const std::string key = "#include \"";
        if (line.compare(0, key.size(), key) == 0) {
            const size_t end = line.find('"', key.size());
            if (end == std::string::npos)
                throw Error(file_error(dir + "/" + name, "malformed #include: " + line));
            out += read_text(dir + "/" + line.substr(key.size(), end - key.size()));
        } else {
            out += line;
        }
        out += '\n';
        if (line.compare(0, 8, "#version") == 0) out += defines;
    }
    return out;
}

GLuint compile(GLenum type, const std::string& dir, const std::string& name,
               const std::string& defines) {
    const std::string src = load_source(dir, name, defines);
    GLuint s = glCreateShader(type);
    const char* p = src.c_str();
    glShaderSource(s, 1, &p, nullptr);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        GLint len = 0;
        glGetShaderiv(s, GL_INFO_LOG_LENGTH, &len);
        std::string log(std::max(len, 1), '\0');
        glGetShaderInfoLog(s, len, nullptr, &log[0]);
        glDeleteShader(s);
        throw Error(file_error(dir + "/" + name, "GLSL compile failed: " + log));
    }
    return s;
}

}  // namespace

namespace gl_util {

GLuint link_program(const std::string& dir, const std::string& frag, const std::string& vert,
                    const std::string& defines) {
    GLuint vs = compile(GL_VERTEX_SHADER, dir, vert, "");
    GLuint fs = 0;
    try {
        fs = compile(GL_FRAGMENT_SHADER, dir, frag, defines);
    } catch (...) {
        glDeleteShader(vs);
        throw;
    }
    GLuint prog = glCreateProgram();
    glAttachShader(prog, vs);
    glAttachShader(prog, fs);
    glLinkProgram(prog);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(prog, GL_LINK_STATUS, &ok);
    if (!ok) {
        GLint len = 0;
        glGetProgramiv(prog, GL_INFO_LOG_LENGTH, &len);
        std::string log(std::max(len, 1), '\0');
        glGetProgramInfoLog(prog, len, nullptr, &log[0]);
        glDeleteProgram(prog);
        throw Error(file_error(dir + "/" + frag, "GLSL link failed: " + log));
    }
    return prog;
}

namespace {
GLuint new_texture() {
    GLuint t = 0;
    glGenTextures(1, &t);
    glBindTexture(GL_TEXTURE_2D, t);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return t;
}
}  // namespace

void allocate(GLuint& tex, GLenum internal, int w, int h, GLenum format, const float* data,
              bool linear) {
    if (!tex) tex = new_texture();
    glBindTexture(GL_TEXTURE_2D, tex);
    // The exact passes read with texelFetch; nearest keeps the sampler complete without mipmaps.
    const GLint filter = linear ? GL_LINEAR : GL_NEAREST;
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, filter);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, filter);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
    glTexImage2D(GL_TEXTURE_2D, 0, internal, w, h, 0, format, GL_FLOAT, data);
}

void delete_texture(GLuint& t) {
    if (t) glDeleteTextures(1, &t);
    t = 0;
}

void bind_sampler(GLuint prog, const char* name, int unit, GLuint tex) {
    glActiveTexture(GL_TEXTURE0 + unit);
    glBindTexture(GL_TEXTURE_2D, tex);
    glUniform1i(glGetUniformLocation(prog, name), unit);
}

void set_int(GLuint prog, const char* name, int v) {
    glUniform1i(glGetUniformLocation(prog, name), v);
}
void set_float(GLuint prog, const char* name, double v) {
    glUniform1f(glGetUniformLocation(prog, name), static_cast<float>(v));
}

}  // namespace gl_util

namespace {

using namespace gl_util;

// Uploads 1/2/4 channels as R32F/RG32F/RGBA32F; 3 channels become RGBA with a = `alpha_fill`,
// or a = `alpha` (1 channel) when given.
void upload(GLuint& tex, const Image& img, const Image* alpha = nullptr) {
    if (img.channels == 1) return allocate(tex, GL_R32F, img.width, img.height, GL_RED, img.data());
    if (img.channels == 2) return allocate(tex, GL_RG32F, img.width, img.height, GL_RG, img.data());
    std::vector<float> rgba(static_cast<size_t>(img.width) * img.height * 4);
    for (size_t i = 0, n = static_cast<size_t>(img.width) * img.height; i < n; ++i) {
        for (int c = 0; c < 3; ++c) rgba[i * 4 + c] = img.pixels[i * img.channels + c];
        rgba[i * 4 + 3] = alpha ? alpha->pixels[i]
                                : (img.channels >= 4 ? img.pixels[i * img.channels + 3] : 1.0f);
    }
    allocate(tex, GL_RGBA32F, img.width, img.height, GL_RGBA, rgba.data());
}

// GL state the passes change, put back on scope exit (the studio draws ImGui after us).
struct StateGuard {
    GLint fbo = 0, viewport[4] = {0, 0, 0, 0}, program = 0, vao = 0, active = 0;
    GLint blend_src_rgb = 0, blend_dst_rgb = 0, blend_src_a = 0, blend_dst_a = 0;
    GLint blend_eq_rgb = 0, blend_eq_a = 0;
    GLboolean blend, depth, scissor, point_size;
    StateGuard() {
        glGetIntegerv(GL_DRAW_FRAMEBUFFER_BINDING, &fbo);
        glGetIntegerv(GL_VIEWPORT, viewport);
        glGetIntegerv(GL_CURRENT_PROGRAM, &program);
        glGetIntegerv(GL_VERTEX_ARRAY_BINDING, &vao);
        glGetIntegerv(GL_ACTIVE_TEXTURE, &active);
        blend = glIsEnabled(GL_BLEND);
        depth = glIsEnabled(GL_DEPTH_TEST);
        scissor = glIsEnabled(GL_SCISSOR_TEST);
        point_size = glIsEnabled(GL_PROGRAM_POINT_SIZE);
        glGetIntegerv(GL_BLEND_SRC_RGB, &blend_src_rgb);
        glGetIntegerv(GL_BLEND_DST_RGB, &blend_dst_rgb);
        glGetIntegerv(GL_BLEND_SRC_ALPHA, &blend_src_a);
        glGetIntegerv(GL_BLEND_DST_ALPHA, &blend_dst_a);
        glGetIntegerv(GL_BLEND_EQUATION_RGB, &blend_eq_rgb);
        glGetIntegerv(GL_BLEND_EQUATION_ALPHA, &blend_eq_a);
        glDisable(GL_BLEND);
        glDisable(GL_DEPTH_TEST);
        glDisable(GL_SCISSOR_TEST);
    }
    ~StateGuard() {
        glBindFramebuffer(GL_FRAMEBUFFER, static_cast<GLuint>(fbo));
        glViewport(viewport[0], viewport[1], viewport[2], viewport[3]);
        glUseProgram(static_cast<GLuint>(program));
        glBindVertexArray(static_cast<GLuint>(vao));
        glActiveTexture(static_cast<GLenum>(active));
        if (blend) glEnable(GL_BLEND);
        if (depth) glEnable(GL_DEPTH_TEST);
        if (scissor) glEnable(GL_SCISSOR_TEST);
        if (point_size)
            glEnable(GL_PROGRAM_POINT_SIZE);
        else
            glDisable(GL_PROGRAM_POINT_SIZE);
        glBlendFuncSeparate(static_cast<GLenum>(blend_src_rgb), static_cast<GLenum>(blend_dst_rgb),
                            static_cast<GLenum>(blend_src_a), static_cast<GLenum>(blend_dst_a));
        glBlendEquationSeparate(static_cast<GLenum>(blend_eq_rgb), static_cast<GLenum>(blend_eq_a));
    }
};

}  // namespace

std::string GlPreview::default_shader_dir() {
    return SHADER_SOURCE_DIR;
}

GlPreview::GlPreview(const std::string& shader_dir) : m_dir(shader_dir) {
    m_composite_prog = link_program(m_dir, "composite.frag");
    m_prep_prog = link_program(m_dir, "dof_prep.frag");
    m_tiles_prog = link_program(m_dir, "dof_tiles.frag");
    m_dof_prog = link_program(m_dir, "dof.frag");
    glGenVertexArrays(1, &m_vao);
    glGenFramebuffers(1, &m_fbo);
    // 1×1 placeholders so that every sampler is complete before the first upload.
    const float zero[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (GLuint* t :
         {&m_bg_atlas, &m_fg_atlas, &m_bg_uv, &m_fg_uv, &m_alpha, &m_bg_depth, &m_fg_depth})
        allocate(*t, GL_RGBA32F, 1, 1, GL_RGBA, zero);
}

GlPreview::~GlPreview() {
    for (GLuint* t :
         {&m_bg_atlas, &m_fg_atlas,  &m_bg_uv,      &m_fg_uv,      &m_alpha,      &m_bg_depth,
          &m_fg_depth, &m_composite, &m_background, &m_foreground, &m_prep0[0],   &m_prep0[1],
          &m_prep1[0], &m_prep1[1],  &m_tiles[0],   &m_tiles[1],   &m_blurred_bg, &m_result,
          &m_shape_tx, &m_area_tx,   &m_bg_fix,     &m_fg_fix})
        delete_texture(*t);
    for (GLuint* t :
         {&m_fast_tiles, &m_fast_dilated, &m_half_bg, &m_half_fg, &m_half_alpha, &m_half_sprite[0],
          &m_half_sprite[1], &m_half_spot[0], &m_half_spot[1], &m_half_sum[0], &m_half_sum[1],
          &m_half_weight[0], &m_half_weight[1], &m_sprite_sum[0], &m_sprite_sum[1]})
        delete_texture(*t);
    for (GLuint p : {m_composite_prog, m_prep_prog, m_tiles_prog, m_dof_prog, m_fast_tiles_prog,
                     m_fast_dilate_prog, m_fast_down_prog, m_fast_gather_prog, m_sprite_prog,
                     m_fast_prog[0][1], m_fast_prog[0][2], m_fast_prog[1][0], m_fast_prog[1][1],
                     m_fast_prog[1][2]})
        if (p) glDeleteProgram(p);
    if (m_vao) glDeleteVertexArrays(1, &m_vao);
    if (m_fbo) glDeleteFramebuffers(1, &m_fbo);
}

unsigned int GlPreview::result_texture() const {
    return m_result_is_composite ? m_composite : m_result;
}

void GlPreview::ensure_size(int w, int h) {
    if (w == m_width && h == m_height && m_composite) return;
    m_width = w;
    m_height = h;
    m_tiles_w = (w + kPreviewTileSize - 1) / kPreviewTileSize;
    m_tiles_h = (h + kPreviewTileSize - 1) / kPreviewTileSize;
    for (GLuint* t : {&m_composite, &m_background, &m_foreground, &m_prep0[0], &m_prep0[1],
                      &m_blurred_bg, &m_result})
        allocate(*t, GL_RGBA32F, w, h, GL_RGBA, nullptr);
    for (GLuint* t : {&m_prep1[0], &m_prep1[1]}) allocate(*t, GL_RG32F, w, h, GL_RG, nullptr);
    for (GLuint* t : {&m_tiles[0], &m_tiles[1]})
        allocate(*t, GL_R32F, m_tiles_w, m_tiles_h, GL_RED, nullptr);
}

void GlPreview::set_atlases(const Image& background_atlas, const Image& foreground_atlas) {
    if (background_atlas.empty() || background_atlas.channels < 3)
        throw Error("GL preview: the background atlas needs >= 3 channels");
    if (!foreground_atlas.empty() && foreground_atlas.channels < 3)
        throw Error("GL preview: the foreground atlas needs >= 3 channels");
    upload(m_bg_atlas, background_atlas);
    if (!m_has_fg_atlas && !foreground_atlas.empty()) m_fg_frame = false;
    m_has_fg_atlas = !foreground_atlas.empty();
    if (m_has_fg_atlas) upload(m_fg_atlas, foreground_atlas);
    m_need_composite = true;
}

void GlPreview::set_frame(const Image& background_uv, const Image& foreground_uv,
                          const Image& alpha) {
    if (background_uv.empty() || background_uv.channels != 2)
        throw Error("GL preview: the background UV map needs 2 channels");
    const int w = background_uv.width, h = background_uv.height;
    upload(m_bg_uv, background_uv);
    m_has_fix = false;  // a frame's fix comes with it (set_frame_fix)
    if (m_has_fg_atlas) {
        if (foreground_uv.width != w || foreground_uv.height != h || foreground_uv.channels != 2)
            throw Error("GL preview: the foreground UV map must be 2 channels, frame size");
        if (alpha.width != w || alpha.height != h || alpha.channels != 1)
            throw Error("GL preview: the alpha map must be 1 channel, frame size");
        upload(m_fg_uv, foreground_uv);
        upload(m_alpha, alpha);
        m_fg_frame = true;
    }
    ensure_size(w, h);
    m_need_composite = true;
}

void GlPreview::set_frame_fix(const Image& background_fix, const Image& foreground_fix) {
    m_has_fix = !background_fix.empty();
    if (!m_has_fix) return;
    if (background_fix.width != m_width || background_fix.height != m_height ||
        background_fix.channels != 3)
        throw Error("GL preview: the background fix must be 3 channels, frame size");
    upload(m_bg_fix, background_fix);
    if (!foreground_fix.empty()) {
        if (!foreground_fix.same_shape(background_fix))
            throw Error("GL preview: the foreground fix must be 3 channels, frame size");
        upload(m_fg_fix, foreground_fix);
    } else {
        upload(m_fg_fix, Image(m_width, m_height, 3));
    }
    m_need_composite = true;
}

void GlPreview::set_layers(const PreviewLayers& layers) {
    const int w = layers.background.width, h = layers.background.height;
    if (layers.background.channels != 3 || !layers.foreground.same_shape(layers.background) ||
        layers.alpha.width != w || layers.alpha.height != h || layers.alpha.channels != 1)
        throw Error(
            "GL preview: layers must be background 3, foreground 3, alpha 1 channels "
            "of one size");
    ensure_size(w, h);
    upload(m_background, layers.background);
    upload(m_foreground, layers.foreground, &layers.alpha);
    m_need_composite = false;
    m_composited = false;
}

void GlPreview::set_depth(const PreviewDepth& depth) {
    m_has_bg_depth = !depth.background.empty();
    m_has_fg_depth = !depth.foreground.empty();
    if (m_has_bg_depth) upload(m_bg_depth, depth.background);
    if (m_has_fg_depth) upload(m_fg_depth, depth.foreground);
    if ((m_has_bg_depth && depth.background.channels != 1) ||
        (m_has_fg_depth && depth.foreground.channels != 1))
        throw Error("GL preview: inverse depth maps need 1 channel");
    m_bg_depth_w = depth.background.width;
    m_bg_depth_h = depth.background.height;
    m_fg_depth_w = depth.foreground.width;
    m_fg_depth_h = depth.foreground.height;
    m_bg_depth_const = depth.background_const;
    m_fg_depth_const = depth.foreground_const;
}

void GlPreview::ensure_tables(const PreviewLens& lens) {
    if (lens.beta == m_table_beta && lens.blades == m_table_blades &&
        lens.rotation_deg == m_table_rotation && lens.max_radius == m_table_max_radius)
        return;
    const std::vector<float> shape = preview_shape_table(lens);
    const std::vector<float> area = preview_area_table(lens, shape);
    m_window = preview_window(lens);
    const int side = 2 * m_window + 1;
    allocate(m_shape_tx, GL_R32F, side, side, GL_RED, shape.data());
    allocate(m_area_tx, GL_R32F, static_cast<int>(area.size()), 1, GL_RED, area.data());
    fit_area_table(area, kPreviewAreaSteps, m_area_fit);
    m_table_beta = lens.beta;
    m_table_blades = lens.blades;
    m_table_rotation = lens.rotation_deg;
    m_table_max_radius = lens.max_radius;
}

void GlPreview::draw(unsigned int program, int w, int h,
                     std::initializer_list<unsigned int> targets, int count,
                     unsigned int primitive) {
    glBindFramebuffer(GL_FRAMEBUFFER, m_fbo);
    GLenum buffers[8];
    int i = 0;
    for (unsigned int t : targets) {
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0 + i, GL_TEXTURE_2D, t, 0);
        buffers[i] = GL_COLOR_ATTACHMENT0 + i;
        ++i;
    }
    for (int j = i; j < 8; ++j)
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0 + j, GL_TEXTURE_2D, 0, 0);
    glDrawBuffers(i, buffers);
    const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE)
        throw Error("GL preview: framebuffer incomplete (status 0x" + [&] {
            std::ostringstream s;
            s << std::hex << status;
            return s.str();
        }() + ")");
    glViewport(0, 0, w, h);
    glBindVertexArray(m_vao);
    if (count < 0) return;  // the targets bound, to be cleared
    if (count > 0)
        glDrawArrays(primitive, 0, count);
    else
        glDrawArrays(GL_TRIANGLES, 0, 3);
}

void GlPreview::render(const PreviewLens& lens, PreviewQuality quality) {
    check_preview_lens(lens);
    m_pass_times.clear();
    m_pass_t0 = now_ms();
    if (m_width == 0) throw Error("GL preview: render() before set_frame() or set_layers()");
    if (m_need_composite && m_has_fg_atlas && !m_fg_frame)
        throw Error(
            "GL preview: set_frame() with the foreground UV and alpha maps is needed "
            "after set_atlases() with a foreground atlas");
    if ((m_has_bg_depth && (m_bg_depth_w != m_width || m_bg_depth_h != m_height)) ||
        (m_has_fg_depth && (m_fg_depth_w != m_width || m_fg_depth_h != m_height)))
        throw Error("GL preview: inverse depth maps must have the frame's size " +
                    std::to_string(m_width) + "x" + std::to_string(m_height));
    StateGuard guard;
    if (m_need_composite) {
        glUseProgram(m_composite_prog);
        bind_sampler(m_composite_prog, "u_background_atlas_tx", 0, m_bg_atlas);
        bind_sampler(m_composite_prog, "u_foreground_atlas_tx", 1, m_fg_atlas);
        bind_sampler(m_composite_prog, "u_background_uv_tx", 2, m_bg_uv);
        bind_sampler(m_composite_prog, "u_foreground_uv_tx", 3, m_fg_uv);
        bind_sampler(m_composite_prog, "u_alpha_tx", 4, m_alpha);
        set_int(m_composite_prog, "u_has_foreground", m_has_fg_atlas ? 1 : 0);
        bind_sampler(m_composite_prog, "u_background_fix_tx", 5, m_has_fix ? m_bg_fix : m_bg_uv);
        bind_sampler(m_composite_prog, "u_foreground_fix_tx", 6, m_has_fix ? m_fg_fix : m_bg_uv);
        set_int(m_composite_prog, "u_has_fix", m_has_fix ? 1 : 0);
        draw(m_composite_prog, m_width, m_height, {m_composite, m_background, m_foreground});
        m_need_composite = false;
        m_composited = true;
    }
    // Early pass-through (aperture 0): the composite is the answer.
    m_result_is_composite = lens.aperture == 0.0 && m_composited;
    if (m_result_is_composite) return;

    ensure_tables(lens);
    mark_pass("composite");
    for (int layer = 0; layer < 2; ++layer) {
        const bool fg = layer == 1;
        glUseProgram(m_prep_prog);
        bind_sampler(m_prep_prog, "u_layer_tx", 0, fg ? m_foreground : m_background);
        bind_sampler(m_prep_prog, "u_invdepth_tx", 1, fg ? m_fg_depth : m_bg_depth);
        bind_sampler(m_prep_prog, "u_area_tx", 2, m_area_tx);
        set_int(m_prep_prog, "u_has_invdepth", (fg ? m_has_fg_depth : m_has_bg_depth) ? 1 : 0);
        set_float(m_prep_prog, "u_invdepth_const", fg ? m_fg_depth_const : m_bg_depth_const);
        set_int(m_prep_prog, "u_use_alpha", fg ? 1 : 0);
        set_float(m_prep_prog, "u_aperture", lens.aperture);
        set_float(m_prep_prog, "u_focus", lens.focus);
        set_float(m_prep_prog, "u_max_radius", lens.max_radius);
        set_float(m_prep_prog, "u_highlight_threshold", lens.highlight_threshold);
        set_float(m_prep_prog, "u_highlight_gain", lens.highlight_gain);
        set_int(m_prep_prog, "u_area_steps", kPreviewAreaSteps);
        draw(m_prep_prog, m_width, m_height, {m_prep0[layer], m_prep1[layer]});
    }
    mark_pass("prep");
    if (quality == PreviewQuality::Fast)
        render_fast(lens);
    else
        render_exact(lens);
}

void GlPreview::render_exact(const PreviewLens& lens) {
    for (int layer = 0; layer < 2; ++layer) {
        const bool fg = layer == 1;
        glUseProgram(m_tiles_prog);
        bind_sampler(m_tiles_prog, "u_prep0_tx", 0, m_prep0[layer]);
        set_int(m_tiles_prog, "u_tile_size", kPreviewTileSize);
        set_int(m_tiles_prog, "u_window", m_window);
        draw(m_tiles_prog, m_tiles_w, m_tiles_h, {m_tiles[layer]});

        glUseProgram(m_dof_prog);
        bind_sampler(m_dof_prog, "u_prep0_tx", 0, m_prep0[layer]);
        bind_sampler(m_dof_prog, "u_prep1_tx", 1, m_prep1[layer]);
        bind_sampler(m_dof_prog, "u_tiles_tx", 2, m_tiles[layer]);
        bind_sampler(m_dof_prog, "u_shape_tx", 3, m_shape_tx);
        // The background pass must not sample its own target: it gets the composite (unused).
        bind_sampler(m_dof_prog, "u_background_tx", 4, fg ? m_blurred_bg : m_composite);
        set_int(m_dof_prog, "u_over", fg ? 1 : 0);
        set_int(m_dof_prog, "u_tile_size", kPreviewTileSize);
        set_int(m_dof_prog, "u_window", m_window);
        set_float(m_dof_prog, "u_beta", lens.beta);
        draw(m_dof_prog, m_width, m_height, {fg ? m_result : m_blurred_bg});
    }
    mark_pass("exact gather");
}

void GlPreview::mark_pass(const char* name) {
    if (!m_timing) return;
    glFinish();
    const double t = now_ms();
    m_pass_times.emplace_back(name, t - m_pass_t0);
    m_pass_t0 = t;
}

Image GlPreview::read_texture(unsigned int tex, int w, int h, int channels) const {
    GLint prev = 0;
    glGetIntegerv(GL_READ_FRAMEBUFFER_BINDING, &prev);
    GLuint fbo = 0;
    glGenFramebuffers(1, &fbo);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo);
    glFramebufferTexture2D(GL_READ_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, tex, 0);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    std::vector<float> rgba(static_cast<size_t>(w) * h * 4);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, w, h, GL_RGBA, GL_FLOAT, rgba.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, static_cast<GLuint>(prev));
    glDeleteFramebuffers(1, &fbo);
    Image out(w, h, channels);
    for (size_t i = 0, n = static_cast<size_t>(w) * h; i < n; ++i)
        for (int c = 0; c < channels; ++c) out.pixels[i * channels + c] = rgba[i * 4 + c];
    return out;
}

Image GlPreview::read_composite() const {
    return read_texture(m_composite, m_width, m_height, 3);
}

PreviewLayers GlPreview::read_layers() const {
    PreviewLayers out;
    out.composite = read_composite();
    out.background = read_texture(m_background, m_width, m_height, 3);
    const Image fa = read_texture(m_foreground, m_width, m_height, 4);
    out.foreground = Image(m_width, m_height, 3);
    out.alpha = Image(m_width, m_height, 1);
    for (size_t i = 0, n = static_cast<size_t>(m_width) * m_height; i < n; ++i) {
        for (int c = 0; c < 3; ++c) out.foreground.pixels[i * 3 + c] = fa.pixels[i * 4 + c];
        out.alpha.pixels[i] = fa.pixels[i * 4 + 3];
    }
    return out;
}

Image GlPreview::read_result() const {
    return read_texture(result_texture(), m_width, m_height, 3);
}

}  // namespace refocus
