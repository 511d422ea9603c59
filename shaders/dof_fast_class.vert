#version 330 core
// Fast depth of field, pass 6's geometry: two triangles over each tile of one class, the other
// tiles degenerate. Software GL runs every line of a shader for every pixel whatever its
// branches take, so each class is its own draw with its own program, over its own tiles only
// (the tile classification of real-time engines, without an indirect dispatch).
//   class 0: no foreground colour reaches the tile (foreground only; A_fg = 0)
//   class 1: dilated R ≤ u_small_radius: the exact gather (R < ½: the pixel itself)
//   class 2: larger: own term + half-res sums + sprites
uniform sampler2D u_tiles_tx;  // dof_fast_dilate: (R_bg, R_fg, A_fg, 0)
uniform int u_tile_size;
uniform int u_foreground;
uniform int u_class;
uniform float u_small_radius;
uniform vec2 u_full_size;  // the frame, px

void main() {
    ivec2 n = textureSize(u_tiles_tx, 0);
    int id = gl_VertexID / 6, corner = gl_VertexID % 6;
    ivec2 t = ivec2(id % n.x, id / n.x);
    vec4 v = texelFetch(u_tiles_tx, t, 0);
    float r = u_foreground != 0 ? v.y : v.x;
    int cls = (u_foreground != 0 && v.z <= 0.0) ? 0 : (r <= u_small_radius ? 1 : 2);
    // corners of the two triangles: (0,0) (1,0) (0,1)  (1,0) (1,1) (0,1)
    ivec2 c = ivec2(corner == 1 || corner == 3 || corner == 4 ? 1 : 0,
                    corner == 2 || corner == 4 || corner == 5 ? 1 : 0);
    vec2 xy = min(vec2((t + c) * u_tile_size), u_full_size);
    if (cls != u_class) xy = vec2(0.0);  // degenerate: nothing drawn
    gl_Position = vec4(xy / u_full_size * 2.0 - 1.0, 0.0, 1.0);
}
