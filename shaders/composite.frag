#version 330 core
// Composite pass — paper eq. 1:
//   C(p) = α(p)·A_f(M_f(p)) + (1 − α(p))·A_b(M_b(p))
// A_f, A_b: foreground / background atlases; M_f, M_b: this frame's UV maps (RG, atlas
// coordinates in [−1, 1], align_corners = false), sampled bilinearly with border clamp; α: this
// frame's alpha map. The layers are written too: the depth-of-field pass blurs them separately.
// Non-finite colour, UV or alpha → 0; α clamped to [0, 1].
// CPU twin: refocus::composite_layers (engine/render/preview.cpp).
#include "preview_lib.glsl"

uniform sampler2D u_background_atlas_tx;  // RGB(A)
uniform sampler2D u_foreground_atlas_tx;  // RGB(A)
uniform sampler2D u_background_uv_tx;     // RG, frame size
uniform sampler2D u_foreground_uv_tx;     // RG, frame size
uniform sampler2D u_alpha_tx;             // R, frame size
uniform int u_has_foreground;             // 0: one-layer clip, F = 0, α = 0
// What the exported plate adds to each layer over the sampled atlas (the output rules and the
// low-frequency lock): RGB, frame size; u_has_fix 0: none.
uniform sampler2D u_background_fix_tx;
uniform sampler2D u_foreground_fix_tx;
uniform int u_has_fix;

layout(location = 0) out vec4 o_composite;   // (C, 1)
layout(location = 1) out vec4 o_background;  // (B, 1)
layout(location = 2) out vec4 o_foreground;  // (F, α), F straight

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec3 b = sample_atlas(u_background_atlas_tx, texelFetch(u_background_uv_tx, p, 0).rg);
    vec3 f = vec3(0.0);
    float a = 0.0;
    if (u_has_foreground != 0) {
        f = sample_atlas(u_foreground_atlas_tx, texelFetch(u_foreground_uv_tx, p, 0).rg);
        a = clamp01(finite_or_zero(texelFetch(u_alpha_tx, p, 0).r));
    }
    if (u_has_fix != 0) {
        vec3 fb = texelFetch(u_background_fix_tx, p, 0).rgb;
        vec3 ff = texelFetch(u_foreground_fix_tx, p, 0).rgb;
        for (int k = 0; k < 3; ++k) {
            b[k] += finite_or_zero(fb[k]);
            if (u_has_foreground != 0) f[k] += finite_or_zero(ff[k]);
        }
    }
    vec3 c;
    for (int k = 0; k < 3; ++k) c[k] = a * f[k] + (1.0 - a) * b[k];  // eq. 1
    o_composite = vec4(c, 1.0);
    o_background = vec4(b, 1.0);
    o_foreground = vec4(f, a);
}
