#version 330 core
// Fast depth of field, pass 1: per-tile extremes of both layers, one texel per tile
// (u_tile_size² px):  (max r_bg, max r_fg, max a_fg, min r_bg).
// dof_fast_dilate grows them to what can reach the tile.
uniform sampler2D u_bg_prep0_tx;  // (c', r)
uniform sampler2D u_fg_prep0_tx;  // (a·c', r)
uniform sampler2D u_fg_prep1_tx;  // (a, 1/K)
uniform int u_tile_size;

layout(location = 0) out vec4 o_tile;

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    ivec2 n = textureSize(u_bg_prep0_tx, 0);
    ivec2 lo = t * u_tile_size, hi = min(lo + u_tile_size, n);
    vec3 m = vec3(0.0);
    for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) {
            m.x = max(m.x, texelFetch(u_bg_prep0_tx, ivec2(x, y), 0).a);
            m.y = max(m.y, texelFetch(u_fg_prep0_tx, ivec2(x, y), 0).a);
            m.z = max(m.z, texelFetch(u_fg_prep1_tx, ivec2(x, y), 0).r);
        }
    o_tile = vec4(m, 0.0);
}
