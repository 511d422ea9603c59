#pragma once
// GL helpers shared by gl_preview.cpp (the exact passes) and gl_preview_fast.cpp (the fast
// path); internal to refocus_glpreview. Need a current GL context.
#include <string>
#include <vector>

namespace refocus::gl_util {

// Compiles `frag` (and `vert`) from `dir`, splicing #include "name" lines. Throws refocus::Error
// naming the file and the GL log.
// `defines` ("#define X 1\n" lines) go after the fragment shader's #version line.
unsigned int link_program(const std::string& dir, const std::string& frag,
                          const std::string& vert = "fullscreen.vert",
                          const std::string& defines = "");
// (Re)allocates `tex` (made if 0) as w × h of `internal`; `linear`: bilinear filtering (the fast
// path's half-resolution textures), else nearest (texelFetch only).
void allocate(unsigned int& tex, unsigned int internal, int w, int h, unsigned int format,
              const float* data, bool linear = false);
void delete_texture(unsigned int& tex);
void bind_sampler(unsigned int prog, const char* name, int unit, unsigned int tex);
void set_int(unsigned int prog, const char* name, int v);
void set_float(unsigned int prog, const char* name, double v);

// Least-squares fit, relative to K, of K(r) ≈ c2·r² + c1·r + c0 to the kernel-area table
// (preview_area_table, `steps` entries per px) over r ≥ 2: the fast gather's K without a fetch.
void fit_area_table(const std::vector<float>& area, int steps, float out[3]);

}  // namespace refocus::gl_util
