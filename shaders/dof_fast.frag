#version 330 core
// Fast depth of field, pass 6 (full resolution, per layer and tile class, drawn over the tiles
// of its class by dof_fast_class.vert): the background writes B̂, the foreground
// out = F̂ + (1 − Â)·B̂. Variants (#define from ui/gl_preview_fast.cpp):
//   FAST_FOREGROUND 0 / 1: the layer;
//   FAST_CLASS 0  no foreground colour reaches the tile: (F̂, Â) = (0, 0), as the exact sum is;
//   FAST_CLASS 1  dilated R ≤ u_small_radius: the exact gather (gather_exact, dof.frag's loop;
//                 ≤ 21 taps at 1.5 px; R < ½: the pixel itself, the early pass-through);
//   FAST_CLASS 2  the pixel's own term at full resolution plus the half-resolution sums of the
//                 others (dof_fast_gather, upsampled bilinearly) and the highlight sprites
//                 (dof_sprite), normalised as the exact gather is:
//     (F̂, Â) = (w_p·(a·c_g, a)_p + (W − w_p)·(a·c_g, a)_near + (S_c, S_a) + (X, 0)) / (W + S_w),
//     W = max(w_p, core_share) (dof_fast_lib): the weight of the sources inside the core (the
//     disk no sample stands for), taken as of the pixel's radius; at least the pixel's own
//     weight w_p = k(r_p)·min(r_p + ½, 1)/K(r_p) (paper eq. 2 at ρ = 0, K from the exact table),
//     which takes the pixel's colour, the rest W − w_p its neighbourhood's (half-res, bilinear).
//   Keeping the own term at full resolution is what stops a sharp pixel next to a blurred area
//   from going soft, and what a bilateral upsample would otherwise have to guess.
#include "preview_lib.glsl"
#include "dof_gather_lib.glsl"
#include "dof_fast_lib.glsl"

uniform sampler2D u_prep0_tx;       // (a·c', r)
uniform sampler2D u_prep1_tx;       // (a, 1/K)
uniform sampler2D u_tiles_tx;       // dof_fast_dilate: (R_bg, R_fg, A_fg, 0)
uniform sampler2D u_shape_tx;       // exact ρ table, centre (u_window, u_window)
uniform sampler2D u_sum_tx;         // half res, bilinear: (Σ w·a·c_g, Σ w·a)
uniform sampler2D u_weight_tx;      // half res, bilinear: Σ w (foreground; a = 1 behind)
uniform sampler2D u_sprite_tx;      // full res: (Σ w·a·excess, 0)
uniform sampler2D u_src_tx;         // half res, bilinear: (a·c_g, r)  (dof_fast_down)
uniform sampler2D u_alpha_tx;       // half res, bilinear: a (foreground)
uniform sampler2D u_background_tx;  // B̂ (foreground only)
uniform int u_tile_size;
uniform int u_window;
uniform float u_beta;
uniform int u_samples;
uniform float u_highlight_level;
uniform float u_sprite_min_radius;

layout(location = 0) out vec4 o_color;

vec4 resolve_large(ivec2 p, float big_r) {
    vec4 p0 = texelFetch(u_prep0_tx, p, 0);
    vec2 p1 = texelFetch(u_prep1_tx, p, 0).rg;
    vec3 own = p0.rgb - highlight_excess(p0.rgb, p1.r, p0.a, u_highlight_level,
                                         u_sprite_min_radius);
    float reach = big_r + 0.5;
    // The core: sample 0's disk, and at least the 2 px between half-res samples (a source
    // nearer than that is in the pixel's own 2×2 block, which no sample reads).
    float core = max(reach / sqrt(float(fast_sample_count(reach, u_samples))), 2.0);
    float w_own = fast_kernel(p0.a, u_beta) * min(p0.a + 0.5, 1.0) * p1.g;
    float w = max(w_own, core_share(p0.a, core));
    vec2 uv = (vec2(p) + 0.5) / (2.0 * vec2(textureSize(u_sum_tx, 0)));
    // The core's sources other than the pixel: its neighbourhood, the half-res sources read
    // bilinearly at p (a tent about 3 px wide), so that r of 1 or 2 px blurs rather than stays.
    vec3 near = texture(u_src_tx, uv).rgb;
    vec4 s = texture(u_sum_tx, uv);
#if FAST_FOREGROUND
    float near_a = texture(u_alpha_tx, uv).r;
    float sw = texture(u_weight_tx, uv).r;
#else
    float near_a = 1.0;
    float sw = s.a;  // the background's a = 1: Σw·a = Σw
#endif
    vec3 x = texelFetch(u_sprite_tx, p, 0).rgb;
    float norm = 1.0 / (w + sw);
    vec3 core_c = w_own * own + (w - w_own) * near;
    float core_a = w_own * p1.r + (w - w_own) * near_a;
    return vec4((core_c + s.rgb + x) * norm, (core_a + s.a) * norm);
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 tile = texelFetch(u_tiles_tx, p / u_tile_size, 0);
    float big_r = FAST_FOREGROUND != 0 ? tile.y : tile.x;
#if FAST_CLASS == 0
    vec4 layer = vec4(0.0);
#elif FAST_CLASS == 1
    vec4 layer = gather_exact(u_prep0_tx, u_prep1_tx, u_shape_tx, p, big_r, u_window, u_beta);
#else
    vec4 layer = resolve_large(p, big_r);
#endif
#if FAST_FOREGROUND
    vec3 b = texelFetch(u_background_tx, p, 0).rgb;
    vec3 c;
    for (int k = 0; k < 3; ++k) c[k] = layer[k] + (1.0 - layer.a) * b[k];
    o_color = vec4(c, 1.0);
#else
    o_color = vec4(layer.rgb, 1.0);
#endif
}
