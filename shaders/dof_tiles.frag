#version 330 core
// Depth of field, pass 2 of 3 (per layer): early-out tiles.
//   R(t) = max { r_q : q within D px (Chebyshev) of tile t },  D = floor(u_max_radius + ½),
// the largest radius that can reach a pixel of tile t (a source q reaches p only when
// ρ(p − q) < r_q + ½ ≤ u_max_radius + ½). The gather at p uses the window floor(R + ½); R < ½
// is the early pass-through (one tap). One output texel per u_tile_size² pixels.
// CPU twin: tile_max (engine/render/preview.cpp).
uniform sampler2D u_prep0_tx;  // (a·c', r)
uniform int u_tile_size;
uniform int u_window;          // D

layout(location = 0) out vec4 o_tile;

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    ivec2 n = textureSize(u_prep0_tx, 0);
    int x0 = max(t.x * u_tile_size - u_window, 0);
    int x1 = min(t.x * u_tile_size + u_tile_size - 1 + u_window, n.x - 1);
    int y0 = max(t.y * u_tile_size - u_window, 0);
    int y1 = min(t.y * u_tile_size + u_tile_size - 1 + u_window, n.y - 1);
    float m = 0.0;
    for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) m = max(m, texelFetch(u_prep0_tx, ivec2(x, y), 0).a);
    o_tile = vec4(m, 0.0, 0.0, 0.0);
}
