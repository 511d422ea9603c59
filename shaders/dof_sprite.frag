#version 330 core
// Fast depth of field, pass 5 (per layer): a highlight's disk, added (blend ONE, ONE) to the
// colour sums of the pixels it reaches: w(p, q)·excess_q with the exact gather's weight
//   w(p, q) = k(r_q − ρ)·clamp(r_q − ρ + ½, 0, 1) / K(r_q)   (paper eq. 2, its rim included),
// ρ = ρ_n(p − q) for n blades, so the bokeh shape of highlights is exact. The weight itself is
// already in the gather's Σw (the source is there with its colour less the excess).
#include "preview_lib.glsl"
#include "dof_fast_lib.glsl"

uniform float u_beta;
uniform int u_blades;

flat in vec3 v_excess;
flat in float v_radius;
flat in vec2 v_centre;
flat in float v_inv_area;

layout(location = 0) out vec4 o_sum;

void main() {
    vec2 o = gl_FragCoord.xy - v_centre;  // p − q
    float rho = shape_rho(o, u_blades);
    float edge = v_radius - rho + 0.5;
    if (edge <= 0.0) discard;
    float w = fast_kernel(v_radius - rho, u_beta) * min(edge, 1.0) * v_inv_area;
    o_sum = vec4(w * v_excess, 0.0);
}
