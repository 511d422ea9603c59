#version 330 core
// Depth of field, pass 3 of 3 (per layer): layered disk bokeh, scatter-as-gather.
//   w(p, q) = k(r_q − ρ(p − q))·clamp(r_q − ρ(p − q) + ½, 0, 1) / K(r_q)
//     k: paper eq. 2, k = e^{βd}/(e^{βd} − d), d = r − ρ (soap-bubble rim at d = 1/β);
//     the clamp: a half-pixel anti-aliased edge, so q reaches p only when ρ < r_q + ½ — the
//     *source's* radius decides, so a sharp source never spreads and a blurred one does;
//     K(r_q): the kernel's discrete area (per-source normalisation, from dof_prep);
//     ρ: |o| for a circle, ρ·cos(φ' − π/n)/cos(π/n) for n blades (φ' the angle from a vertex
//     modulo 2π/n), read from a table the CPU twin builds and uses too.
//   Layer:  F̂ = Σ_q w·a_q·c'_q / Σ_q w,   Â = Σ_q w·a_q / Σ_q w   (q inside the image).
//   Layered (DESIGN.md render; paper §3.3 on occluded areas at the silhouette): the background
//   pass writes B̂; the foreground pass (u_over = 1) writes  out = F̂ + (1 − Â)·B̂,  so an
//   in-focus foreground edge does not bleed onto the blurred background, and a blurred
//   foreground edge reveals the background layer behind it.
//   Early pass-through: window floor(R_tile + ½) = 0 → the pixel itself.
// CPU twin: gather and render_dof (engine/render/preview.cpp).
#include "preview_lib.glsl"

uniform sampler2D u_prep0_tx;       // (a·c', r)
uniform sampler2D u_prep1_tx;       // (a, 1/K)
uniform sampler2D u_tiles_tx;       // R: largest radius reaching the tile
uniform sampler2D u_shape_tx;       // R, (2D+1)²: ρ(o) at offset o = p − q, centre (D, D)
uniform sampler2D u_background_tx;  // B̂ (u_over = 1 only)
uniform int u_over;
uniform int u_tile_size;
uniform int u_window;               // D
uniform float u_beta;

layout(location = 0) out vec4 o_color;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 n = textureSize(u_prep0_tx, 0);
    float rwin = texelFetch(u_tiles_tx, p / u_tile_size, 0).r;
    int half_w = int(floor(rwin + 0.5));
    vec4 layer;
    if (half_w == 0) {  // early pass-through: nothing within reach is blurred
        layer = vec4(texelFetch(u_prep0_tx, p, 0).rgb, texelFetch(u_prep1_tx, p, 0).r);
    } else {
        float sr = 0.0, sg = 0.0, sb = 0.0, sa = 0.0, sw = 0.0;
        // Taps with dx² + dy² ≥ (R + ½)² add exactly 0 (ρ_n ≥ ρ): skip them per row (+1 px
        // against rounding; the twin need not skip the same ones).
        float reach2 = (rwin + 0.5) * (rwin + 0.5);
        for (int dy = -half_w; dy <= half_w; ++dy) {
            int qy = p.y + dy;
            if (qy < 0 || qy >= n.y) continue;
            int span = min(half_w, int(sqrt(max(reach2 - float(dy * dy), 0.0))) + 1);
            for (int dx = -span; dx <= span; ++dx) {
                int qx = p.x + dx;
                if (qx < 0 || qx >= n.x) continue;
                vec4 p0 = texelFetch(u_prep0_tx, ivec2(qx, qy), 0);
                vec2 p1 = texelFetch(u_prep1_tx, ivec2(qx, qy), 0).rg;
                float rho = texelFetch(u_shape_tx, ivec2(u_window - dx, u_window - dy), 0).r;
                float rq = p0.a;
                float edge = rq - rho + 0.5;
                if (edge <= 0.0) continue;
                float wgt = disk_kernel(rq - rho, u_beta) * min(edge, 1.0) * p1.g;
                sr += wgt * p0.r;
                sg += wgt * p0.g;
                sb += wgt * p0.b;
                sa += wgt * p1.r;
                sw += wgt;
            }
        }
        layer = vec4(sr / sw, sg / sw, sb / sw, sa / sw);
    }
    if (u_over != 0) {
        vec3 b = texelFetch(u_background_tx, p, 0).rgb;
        vec3 c;
        for (int k = 0; k < 3; ++k) c[k] = layer[k] + (1.0 - layer.a) * b[k];
        o_color = vec4(c, 1.0);
    } else {
        o_color = layer;
    }
}
