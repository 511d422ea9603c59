#version 330 core
// Fast depth of field, pass 3 (half resolution): each texel stands for its 2×2 block of sources.
//   gather sources:  (mean of a·c_g, mean r) per layer and mean a (foreground), where
//     c_g = c' less its highlight excess (dof_fast_lib highlight_excess), so that a sparse
//     gather never lands on a lone bright pixel (flicker) or misses it;
//   sprite sources:  (Σ of the block's highlight excess, mean r) per layer and where in the
//     block the excess is, drawn as disks by dof_sprite.
#include "preview_lib.glsl"
#include "dof_fast_lib.glsl"

uniform sampler2D u_bg_prep0_tx;  // (c', r)
uniform sampler2D u_fg_prep0_tx;  // (a·c', r)
uniform sampler2D u_fg_prep1_tx;  // (a, 1/K)
uniform float u_highlight_level;  // luminance above which a source is a highlight
uniform float u_sprite_min_radius;

layout(location = 0) out vec4 o_bg;         // (c_g, r)
layout(location = 1) out vec4 o_fg;         // (a·c_g, r)
layout(location = 2) out vec4 o_fg_alpha;   // (a, 0, 0, 0)
layout(location = 3) out vec4 o_bg_sprite;  // (Σ excess, r)
layout(location = 4) out vec4 o_fg_sprite;  // (Σ a·excess, r)
layout(location = 5) out vec4 o_bg_spot;    // (the excess's centroid − block centre, px, 0, 0)
layout(location = 6) out vec4 o_fg_spot;

void main() {
    ivec2 h = ivec2(gl_FragCoord.xy);
    ivec2 n = textureSize(u_bg_prep0_tx, 0);
    vec4 bg = vec4(0.0), fg = vec4(0.0);
    vec3 bg_x = vec3(0.0), fg_x = vec3(0.0);
    float a_sum = 0.0;
    vec3 spot_b = vec3(0.0), spot_f = vec3(0.0);  // Σ L(excess)·(offset, 1)
    for (int k = 0; k < 4; ++k) {
        ivec2 q = min(2 * h + ivec2(k & 1, k >> 1), n - 1);
        vec4 b = texelFetch(u_bg_prep0_tx, q, 0);
        vec4 f = texelFetch(u_fg_prep0_tx, q, 0);
        float a = texelFetch(u_fg_prep1_tx, q, 0).r;
        vec3 xb = highlight_excess(b.rgb, 1.0, b.a, u_highlight_level, u_sprite_min_radius);
        vec3 xf = highlight_excess(f.rgb, a, f.a, u_highlight_level, u_sprite_min_radius);
        bg += vec4(b.rgb - xb, b.a);
        fg += vec4(f.rgb - xf, f.a);
        vec2 off = vec2(k & 1, k >> 1) - 0.5;
        spot_b += dot(xb, vec3(0.2126, 0.7152, 0.0722)) * vec3(off, 1.0);
        spot_f += dot(xf, vec3(0.2126, 0.7152, 0.0722)) * vec3(off, 1.0);
        bg_x += xb;
        fg_x += xf;
        a_sum += a;
    }
    o_bg = bg * 0.25;
    o_fg = fg * 0.25;
    o_fg_alpha = vec4(a_sum * 0.25, 0.0, 0.0, 0.0);
    o_bg_sprite = vec4(bg_x, bg.a * 0.25);
    o_fg_sprite = vec4(fg_x, fg.a * 0.25);
    // A lone highlight's sprite must sit on its pixel: ½ px off moves a 1 px disk's edge.
    o_bg_spot = vec4(spot_b.z > 0.0 ? spot_b.xy / spot_b.z : vec2(0.0), 0.0, 0.0);
    o_fg_spot = vec4(spot_f.z > 0.0 ? spot_f.xy / spot_f.z : vec2(0.0), 0.0, 0.0);
}
