#version 330 core
// Depth of field, pass 1 of 3 (per layer): radius, highlight boost, per-source normalisation.
//   r = u_aperture·|invdepth − u_focus|  (seed 001 eq. 1.12: radius linear in inverse depth),
//       0 if not finite, clamped to u_max_radius;
//   c' = c·(1 + u_highlight_gain·max(0, L(c) − u_highlight_threshold)·clamp(r − ½, 0, 1)),
//       L = Rec. 709 luminance (highlights boosted before the blur, as bokeh renderers do;
//       sharp pixels untouched);
//   1/K(r): K = Σ_o k(r − ρ(o))·clamp(r − ρ(o) + ½, 0, 1), paper eq. 2 kernel's discrete area,
//       from a table at r = i/steps (linear in between) that the CPU twin builds and uses too.
// Outputs P0 = (a·c', r), P1 = (a, 1/K): a = α (foreground) or 1 (background).
// CPU twin: prepare_layer (engine/render/preview.cpp).
#include "preview_lib.glsl"

uniform sampler2D u_layer_tx;     // (colour, α) of the layer
uniform sampler2D u_invdepth_tx;  // R: inverse depth, when u_has_invdepth != 0
uniform sampler2D u_area_tx;      // R, width = table size, height 1: K(i/steps)
uniform int u_has_invdepth;
uniform float u_invdepth_const;
uniform int u_use_alpha;          // 0: background layer, a = 1
uniform float u_aperture;
uniform float u_focus;
uniform float u_max_radius;
uniform float u_highlight_threshold;
uniform float u_highlight_gain;
uniform int u_area_steps;

layout(location = 0) out vec4 o_prep0;
layout(location = 1) out vec4 o_prep1;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 texel = texelFetch(u_layer_tx, p, 0);
    vec3 c = vec3(finite_or_zero(texel.r), finite_or_zero(texel.g), finite_or_zero(texel.b));
    float a = u_use_alpha != 0 ? clamp01(finite_or_zero(texel.a)) : 1.0;
    float d = u_has_invdepth != 0 ? texelFetch(u_invdepth_tx, p, 0).r : u_invdepth_const;
    float r = u_aperture * abs(d - u_focus);
    r = is_finite(r) ? min(r, u_max_radius) : 0.0;
    float lum = 0.2126 * c.r + 0.7152 * c.g + 0.0722 * c.b;
    float boost = 1.0 + u_highlight_gain * max(lum - u_highlight_threshold, 0.0) * clamp01(r - 0.5);
    int last = textureSize(u_area_tx, 0).x - 1;
    float xr = r * float(u_area_steps);
    float fl = floor(xr);
    int i = min(int(fl), last - 1);
    float f = xr - fl;
    float kar = texelFetch(u_area_tx, ivec2(i, 0), 0).r * (1.0 - f) +
                texelFetch(u_area_tx, ivec2(i + 1, 0), 0).r * f;
    vec3 cp;
    for (int k = 0; k < 3; ++k) cp[k] = finite_or_zero(c[k] * boost) * a;
    o_prep0 = vec4(cp, r);
    o_prep1 = vec4(a, 1.0 / kar, 0.0, 0.0);
}
