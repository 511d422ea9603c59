#version 330 core
// Fullscreen pass: one triangle covering the viewport, generated from gl_VertexID (no vertex
// buffer; the caller binds an empty vertex array). Fragment shaders address texels with
// ivec2(gl_FragCoord.xy), row 0 = image row 0 (the top row of a refocus::Image).
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
