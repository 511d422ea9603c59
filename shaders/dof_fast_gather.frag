#version 330 core
// Fast depth of field, pass 4 (half resolution, per layer): the sums of the exact gather
// (dof.frag) over the sources other than the pixel itself, estimated with N samples of the
// half-resolution sources on a golden-angle spiral that fills the disk of radius R + ½, R the
// tile's dilated radius (so a large radius costs no more taps than a small one), each sample the
// half-resolution texel under it, the pixel's own 2×2 block left to dof_fast.frag:
//   S(p) = Σ_{i≥1} A·w(p, q_i)·(a·c_g, a, 1)_{q_i},   A = π(R + ½)²/N, the area per sample
//   (fast_sample_count; sample 0's core is the pixel's own term in dof_fast.frag),
//   w(p, q) = k(r_q − ρ)·clamp(r_q − ρ + ½, 0, 1) / K(r_q)  (paper eq. 2; the *source's* radius
//   decides whether it reaches p: scatter-as-gather), ρ = ρ_n(p − q) for n blades.
// Sums, not averages: they are linear in the sources and smooth, so dof_fast.frag upsamples them
// bilinearly and adds the pixel's own full-resolution term before normalising. Tiles with
// R ≤ u_small_radius (gathered exactly at full resolution) or no foreground write 0.
// Outputs: (Σ A·w·a·c_g, Σ A·w·a), (Σ A·w, 0, 0, 0); for the background a = 1, so the first
// alone carries its sums.
#include "preview_lib.glsl"
#include "dof_fast_lib.glsl"

uniform sampler2D u_src_tx;    // half res, (a·c_g, r)
uniform sampler2D u_alpha_tx;  // half res, (a, …) (foreground)
uniform sampler2D u_tiles_tx;  // dof_fast_dilate: (R_bg, R_fg, A_fg, 0)
uniform int u_foreground;
uniform int u_tile_size;
uniform float u_small_radius;
uniform int u_samples;         // N at most
uniform vec2 u_spiral[64];     // (cos, sin)(i·golden angle), i < u_samples: no trig per sample
uniform float u_beta;
uniform int u_blades;
uniform vec3 u_area_fit;       // K(r) ≈ c2·r² + c1·r + c0

layout(location = 0) out vec4 o_sum;
layout(location = 1) out vec4 o_weight;

void main() {
    ivec2 h = ivec2(gl_FragCoord.xy);
    // The resolve reads these sums bilinearly, so a texel at a tile's edge serves the tile beside
    // it too: the largest radius (and foreground α) of the tiles its footprint touches, so that
    // no tile gets sums cut short at its border.
    ivec2 nt = textureSize(u_tiles_tx, 0);
    ivec2 lo = max((2 * h - 1) / u_tile_size, 0), hi = min((2 * h + 2) / u_tile_size, nt - 1);
    vec4 tile = vec4(0.0);
    for (int ty = lo.y; ty <= hi.y; ++ty)
        for (int tx = lo.x; tx <= hi.x; ++tx) tile = max(tile, texelFetch(u_tiles_tx, ivec2(tx, ty), 0));
    float big_r = u_foreground != 0 ? tile.y : tile.x;
    o_sum = vec4(0.0);
    o_weight = vec4(0.0);
    // Software GL runs every line for every pixel (masked SIMD) and a loop until no pixel is
    // left in it: a skipped texel costs one masked iteration, not the tile's sample count.
    bool skip = big_r <= u_small_radius || (u_foreground != 0 && tile.z <= 0.0);
    vec2 centre = 2.0 * vec2(h) + 1.0;  // full-res px; equals a pixel centre ± ½
    ivec2 half_n = textureSize(u_src_tx, 0);
    float reach = big_r + 0.5;
    int count = skip ? 0 : fast_sample_count(reach, u_samples);
    float area = 3.14159265 * reach * reach / float(max(count, 1));
    vec4 s = vec4(0.0);
    float sw = 0.0;
    for (int i = 1; i < count; ++i) {  // i = 0: the core, dof_fast.frag's own term
        float rad = reach * sqrt((float(i) + 0.5) / float(count));
        // The sample is the half-res source texel under the spiral point (one fetch, no
        // filtering), and ρ is measured to that texel's centre.
        ivec2 qh = h + ivec2(floor(0.5 * rad * u_spiral[i] + 0.5));
        if (qh.x < 0 || qh.y < 0 || qh.x >= half_n.x || qh.y >= half_n.y || qh == h) continue;
        vec4 src = texelFetch(u_src_tx, qh, 0);
        float rq = src.a;
        float rho = shape_rho(2.0 * vec2(h - qh), u_blades);  // the offset p − q
        float edge = rq - rho + 0.5;
        if (edge <= 0.0) continue;
        float w = area * fast_kernel(rq - rho, u_beta) * min(edge, 1.0) / area_fit(rq, u_area_fit);
        float a = u_foreground != 0 ? texelFetch(u_alpha_tx, qh, 0).r : 1.0;
        s += w * vec4(src.rgb, a);
        sw += w;
    }
    o_sum = s;
    o_weight = vec4(sw, 0.0, 0.0, 0.0);
}
