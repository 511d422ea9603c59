#version 330 core
// Fast depth of field, pass 2: what can reach each tile.
//   R_layer(t) = max { max r of tile s : gap(s, t) < max r of s + ½ }
//   A_fg(t)    = max { max a of fg tile s : gap(s, t) < max r_fg of s + ½ }
// gap: the Chebyshev distance between the nearest pixel centres of s and t, (|Δt| − 1)·T + 1
// (0 for s = t), a lower bound of ρ: a source q reaches p only when ρ(p − q) < r_q + ½.
// R < ½ is the early pass-through; A_fg = 0 means no foreground colour reaches the tile.
// Output: (R_bg, R_fg, A_fg, 0).
uniform sampler2D u_tiles_tx;  // dof_fast_tiles
uniform int u_tile_size;
uniform int u_reach;           // tiles each way: ceil((max_radius + ½ − 1)/T) + 1

layout(location = 0) out vec4 o_tile;

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    ivec2 n = textureSize(u_tiles_tx, 0);
    vec3 m = vec3(0.0);
    for (int dy = -u_reach; dy <= u_reach; ++dy)
        for (int dx = -u_reach; dx <= u_reach; ++dx) {
            ivec2 s = t + ivec2(dx, dy);
            if (s.x < 0 || s.y < 0 || s.x >= n.x || s.y >= n.y) continue;
            int cheb = max(abs(dx), abs(dy));
            float gap = cheb == 0 ? 0.0 : float((cheb - 1) * u_tile_size + 1);
            vec4 v = texelFetch(u_tiles_tx, s, 0);
            if (gap < v.x + 0.5) m.x = max(m.x, v.x);
            if (gap < v.y + 0.5) {
                m.y = max(m.y, v.y);
                m.z = max(m.z, v.z);
            }
        }
    o_tile = vec4(m, 0.0);
}
