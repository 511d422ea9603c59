#version 330 core
// Fast depth of field, pass 5 (per layer): one point per half-resolution texel; a texel with a
// highlight excess (dof_fast_down) becomes a square sprite over its disk, the others are put
// outside the viewport (nothing is drawn: the cost is only where highlights are).
#include "preview_lib.glsl"

uniform sampler2D u_sprite_tx;  // half res: (Σ excess, r)
uniform vec2 u_full_size;       // the frame, px

flat out vec3 v_excess;
flat out float v_radius;
flat out vec2 v_centre;  // full-res px

void main() {
    ivec2 n = textureSize(u_sprite_tx, 0);
    ivec2 h = ivec2(gl_VertexID % n.x, gl_VertexID / n.x);
    vec4 s = texelFetch(u_sprite_tx, h, 0);
    v_excess = s.rgb;
    v_radius = s.a;
    v_centre = 2.0 * vec2(h) + 1.0;
    if (s.r + s.g + s.b <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // clipped
        gl_PointSize = 1.0;
        return;
    }
    gl_Position = vec4(v_centre / u_full_size * 2.0 - 1.0, 0.0, 1.0);
    gl_PointSize = 2.0 * ceil(s.a + 1.0) + 1.0;
}
