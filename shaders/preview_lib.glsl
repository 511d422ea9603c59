// Shared by the preview passes (spliced in by ui/gl_preview.cpp where a pass says
// #include "preview_lib.glsl"). CPU twin: engine/render/preview.cpp, same names.

// An exponent of all ones is Inf or NaN: non-finite inputs count as 0 (bit test, so that no
// fast-math rewrite of x != x can fold it away).
float finite_or_zero(float v) {
    return (floatBitsToUint(v) & 0x7f800000u) == 0x7f800000u ? 0.0 : v;
}
bool is_finite(float v) { return (floatBitsToUint(v) & 0x7f800000u) != 0x7f800000u; }
float clamp01(float v) { return min(max(v, 0.0), 1.0); }

// Paper eq. 2, k = e^{βd}/(e^{βd} − d), d = r − ρ, without overflow: d > 0 uses
// 1/(1 − d·e^{−βd}). Peaks at d = 1/β (the soap-bubble rim), → 1 inside, → 0 outside.
float disk_kernel(float d, float beta) {
    if (d > 0.0) return 1.0 / (1.0 - d * exp(-beta * d));
    float e = exp(beta * d);
    return e / (e - d);
}

// u ∈ [−1, 1] with align_corners = false (texel centre i ↦ (2i + 1)/N − 1) → the two texels
// and the fraction of a bilinear tap, clamped to the border texels.
void atlas_coord(float u, int n, out int i0, out int i1, out float f) {
    float x = ((finite_or_zero(u) + 1.0) * float(n) - 1.0) * 0.5;
    x = min(max(x, 0.0), float(n - 1));
    float fl = floor(x);
    i0 = int(fl);
    i1 = min(i0 + 1, n - 1);
    f = x - fl;
}

// Bilinear over sanitised texels (texelFetch, not the texture unit's filter, whose weights are
// fixed-point on real GPUs: the CPU twin could not match them).
vec3 sample_atlas(sampler2D atlas_tx, vec2 uv) {
    ivec2 n = textureSize(atlas_tx, 0);
    int x0, x1, y0, y1;
    float fx, fy;
    atlas_coord(uv.x, n.x, x0, x1, fx);
    atlas_coord(uv.y, n.y, y0, y1, fy);
    vec3 a00 = texelFetch(atlas_tx, ivec2(x0, y0), 0).rgb;
    vec3 a10 = texelFetch(atlas_tx, ivec2(x1, y0), 0).rgb;
    vec3 a01 = texelFetch(atlas_tx, ivec2(x0, y1), 0).rgb;
    vec3 a11 = texelFetch(atlas_tx, ivec2(x1, y1), 0).rgb;
    vec3 res;
    for (int c = 0; c < 3; ++c) {
        float top = finite_or_zero(a00[c]) * (1.0 - fx) + finite_or_zero(a10[c]) * fx;
        float bot = finite_or_zero(a01[c]) * (1.0 - fx) + finite_or_zero(a11[c]) * fx;
        res[c] = top * (1.0 - fy) + bot * fy;
    }
    return res;
}
