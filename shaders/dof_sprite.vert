#version 330 core
// Fast depth of field, pass 5 (per layer): one point per 2×2 half-resolution texels; a block
// with a highlight excess (dof_fast_down) becomes a square sprite over its disk, the others are
// put outside the clip volume (nothing is drawn: the cost is only where highlights are).
#include "preview_lib.glsl"

uniform sampler2D u_sprite_tx;  // half res: (Σ excess, r)
uniform sampler2D u_spot_tx;    // half res: (the excess's centroid − the texel's centre, px)
uniform vec2 u_full_size;       // the frame, px
uniform sampler2D u_area_tx;    // R, K(i/steps), the exact table (dof_prep.frag)
uniform int u_area_steps;

flat out vec3 v_excess;
flat out float v_radius;
flat out vec2 v_centre;  // full-res px
flat out float v_inv_area;  // 1/K(r), once per sprite from the exact table

void main() {
    ivec2 n = textureSize(u_sprite_tx, 0);
    int cols = (n.x + 1) / 2;
    ivec2 g = ivec2(gl_VertexID % cols, gl_VertexID / cols);
    // The 2×2 half-res texels (4×4 px) as one sprite at their highlights' luminance-weighted
    // centroid and radius: a lone highlight lands where it is, at a quarter of the vertices.
    vec3 e = vec3(0.0);
    vec3 acc = vec3(0.0);  // Σ lum·(centre, r)
    float wsum = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 h = 2 * g + ivec2(k & 1, k >> 1);
        if (h.x >= n.x || h.y >= n.y) continue;
        vec4 s = texelFetch(u_sprite_tx, h, 0);
        float lum = 0.2126 * s.r + 0.7152 * s.g + 0.0722 * s.b;
        e += s.rgb;
        vec2 spot = 2.0 * vec2(h) + 1.0 + texelFetch(u_spot_tx, h, 0).rg;
        acc += lum * vec3(spot, s.a);
        wsum += lum;
    }
    v_excess = e;
    if (wsum <= 0.0) {
        v_radius = 0.0;
        v_centre = vec2(0.0);
        v_inv_area = 0.0;
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // clipped
        gl_PointSize = 1.0;
        return;
    }
    v_centre = acc.xy / wsum;
    v_radius = acc.z / wsum;
    int last = textureSize(u_area_tx, 0).x - 1;
    float xr = v_radius * float(u_area_steps);
    int i = min(int(floor(xr)), last - 1);
    float f = xr - floor(xr);
    v_inv_area = 1.0 / (texelFetch(u_area_tx, ivec2(i, 0), 0).r * (1.0 - f) +
                        texelFetch(u_area_tx, ivec2(i + 1, 0), 0).r * f);
    gl_Position = vec4(v_centre / u_full_size * 2.0 - 1.0, 0.0, 1.0);
    gl_PointSize = 2.0 * v_radius + 3.0;  // the disk, its ½ px edge and a pixel of slack
}
