#version 330 core
// Fast depth of field, pass 6 (full resolution): each layer, then  out = F̂ + (1 − Â)·B̂.
// Per pixel, by its tile's dilated radius R (dof_fast_dilate):
//   R < ½               the pixel itself (early pass-through; exact);
//   R ≤ u_small_radius  the exact gather (gather_exact, dof.frag's loop; ≤ 21 taps at 1.5 px);
//   larger              the pixel's own term at full resolution plus the half-resolution sums
//                       of the others (dof_fast_gather, upsampled bilinearly) and the
//                       highlight sprites (dof_sprite), normalised as the exact gather is:
//     (F̂, Â) = (w_p·(a·c_g, a)_p + (W − w_p)·(a·c_g, a)_near + (S_c, S_a) + (X, 0)) / (W + S_w),
//     W = core_weight (dof_fast_lib): the weight of the sources inside the gather's core (the
//     disk no sample stands for), taken as of the pixel's radius; at least the pixel's own
//     weight w_p = k(r_p)·min(r_p + ½, 1)/K(r_p) (paper eq. 2 at ρ = 0, K from the exact table),
//     which takes the pixel's colour, the rest W − w_p its neighbourhood's (half-res, bilinear).
//   Keeping the own term at full resolution is what stops a sharp pixel next to a blurred area
//   from going soft, and what a bilateral upsample would otherwise have to guess.
// A foreground tile that no foreground colour reaches (A_fg = 0) is (0, 0), as the exact sum is.
#include "preview_lib.glsl"
#include "dof_gather_lib.glsl"
#include "dof_fast_lib.glsl"

uniform sampler2D u_bg_prep0_tx;  // (c', r)
uniform sampler2D u_bg_prep1_tx;  // (1, 1/K)
uniform sampler2D u_fg_prep0_tx;  // (a·c', r)
uniform sampler2D u_fg_prep1_tx;  // (a, 1/K)
uniform sampler2D u_tiles_tx;     // dof_fast_dilate: (R_bg, R_fg, A_fg, 0)
uniform sampler2D u_shape_tx;     // exact ρ table, centre (u_window, u_window)
uniform sampler2D u_bg_sum_tx;    // half res, bilinear: (Σ w·c_g, Σ w)
uniform sampler2D u_bg_weight_tx; // unused: the background's Σw is u_bg_sum_tx's alpha
uniform sampler2D u_fg_sum_tx;    // half res, bilinear: (Σ w·a·c_g, Σ w·a)
uniform sampler2D u_fg_weight_tx; // half res, bilinear: (Σ w, …)
uniform sampler2D u_bg_sprite_tx; // full res: (Σ w·excess, 0)
uniform sampler2D u_fg_sprite_tx; // full res: (Σ w·a·excess, 0)
uniform sampler2D u_bg_src_tx;    // half res, bilinear: (c_g, r)       (dof_fast_down)
uniform sampler2D u_fg_src_tx;    // half res, bilinear: (a·c_g, r)
uniform sampler2D u_fg_alpha_tx;  // half res, bilinear: a
uniform int u_tile_size;
uniform int u_window;
uniform float u_beta;
uniform float u_small_radius;
uniform int u_samples;
uniform float u_highlight_level;
uniform float u_sprite_min_radius;

layout(location = 0) out vec4 o_color;

vec4 resolve(sampler2D prep0_tx, sampler2D prep1_tx, sampler2D sum_tx, sampler2D weight_tx,
             sampler2D sprite_tx, sampler2D src_tx, ivec2 p, float big_r, bool bg) {
    // A branch that differs between neighbouring pixels runs both sides on software GL (masked
    // SIMD): the gather's window is 0 for the pixels that do not take it, so that it costs them
    // one tap instead of a loop over the large radius.
    bool small = big_r <= u_small_radius;
    vec4 exact = gather_exact(prep0_tx, prep1_tx, u_shape_tx, p, small ? big_r : 0.0, u_window,
                              u_beta);
    if (small) return exact;
    vec4 p0 = texelFetch(prep0_tx, p, 0);
    vec2 p1 = texelFetch(prep1_tx, p, 0).rg;
    vec3 own = p0.rgb - highlight_excess(p0.rgb, p1.r, p0.a, u_highlight_level,
                                         u_sprite_min_radius);
    float reach = big_r + 0.5;
    // The core: sample 0's disk, and at least the 2 px between half-res samples (a source
    // nearer than that is in the pixel's own 2×2 block, which no sample reads).
    float core = max(reach / sqrt(float(fast_sample_count(reach, u_samples))), 2.0);
    float w_own = disk_kernel(p0.a, u_beta) * min(p0.a + 0.5, 1.0) * p1.g;
    float w = core_weight(p0.a, p1.g, u_beta, core);
    vec2 uv = (vec2(p) + 0.5) / (2.0 * vec2(textureSize(sum_tx, 0)));
    // The core's sources other than the pixel: its neighbourhood, the half-res sources read
    // bilinearly at p (a tent about 3 px wide), so that r of 1 or 2 px blurs rather than stays.
    vec3 near = texture(src_tx, uv).rgb;
    float near_a = bg ? 1.0 : texture(u_fg_alpha_tx, uv).r;
    vec4 s = texture(sum_tx, uv);
    float sw = bg ? s.a : texture(weight_tx, uv).r;  // the background's a = 1: Σw·a = Σw
    vec3 x = texelFetch(sprite_tx, p, 0).rgb;
    float norm = 1.0 / (w + sw);
    vec3 core_c = w_own * own + (w - w_own) * near;
    float core_a = w_own * p1.r + (w - w_own) * near_a;
    return vec4((core_c + s.rgb + x) * norm, (core_a + s.a) * norm);
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 tile = texelFetch(u_tiles_tx, p / u_tile_size, 0);
    vec4 b = resolve(u_bg_prep0_tx, u_bg_prep1_tx, u_bg_sum_tx, u_bg_weight_tx, u_bg_sprite_tx,
                     u_bg_src_tx, p, tile.x, true);
    vec4 f = vec4(0.0);
    if (tile.z > 0.0)
        f = resolve(u_fg_prep0_tx, u_fg_prep1_tx, u_fg_sum_tx, u_fg_weight_tx, u_fg_sprite_tx,
                    u_fg_src_tx, p, tile.y, false);
    vec3 c;
    for (int k = 0; k < 3; ++k) c[k] = f[k] + (1.0 - f.a) * b[k];
    o_color = vec4(c, 1.0);
}
