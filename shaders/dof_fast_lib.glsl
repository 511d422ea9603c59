// Shared by the fast depth-of-field passes (dof_fast_*.frag, dof_sprite.*). Needs
// preview_lib.glsl first. The fast path approximates dof.frag's exact gather; see
// docs/method.md ("The preview's depth of field").

// ρ_n(o) = |o|·cos(φ' − π/n)/cos(π/n), φ' the angle of o from a vertex modulo 2π/n: the polygon
// distance of preview_shape_table (= r on the polygon of circumradius r). The sector's term is
// the largest projection of o on the edge normals, max_k o·m_k/cos(π/n) (ui/gl_preview_fast.cpp
// passes m_k/cos(π/n)): no atan or cos per sample, and nothing but |o| for a circle.
uniform vec2 u_edge_normals[64];  // m_k/cos(π/n), k < u_blades
float shape_rho(vec2 o, int blades) {
    float m = -1e30;
    for (int k = 0; k < blades; ++k) m = max(m, dot(o, u_edge_normals[k]));
    return blades >= 3 ? m : length(o);
}

// Paper eq. 2, k = e^{βd}/(e^{βd} − d) = 1/(1 − d·e^{−βd}), in the second form for every d: one
// exp, no branch (software GL evaluates both sides of a branch; disk_kernel's split keeps the
// exact path bit-equal to its CPU twin). The exponent is capped: far outside the disk k → 0.
float fast_kernel(float d, float beta) {
    return 1.0 / (1.0 - d * exp(min(-beta * d, 80.0)));
}

// K(r), the kernel's discrete area, as c2·r² + c1·r + c0 fitted to the exact table over the
// lens's radii (ui/gl_preview.cpp fit_area): a texture fetch saved per sample.
float area_fit(float r, vec3 c) {
    return max((c.x * r + c.y) * r + c.z, 0.5);
}

// A highlight: a source with r > min_r whose straight colour's luminance exceeds `level`. Its
// colour above `level` (premultiplied, as `ac`) is drawn as a sprite; the gather keeps the rest.
vec3 highlight_excess(vec3 ac, float a, float r, float level, float min_r) {
    float lum = 0.2126 * ac.r + 0.7152 * ac.g + 0.0722 * ac.b;
    if (r <= min_r || lum <= level * a || lum <= 0.0) return vec3(0.0);
    return ac * (1.0 - level * a / lum);
}

// The fast gather's sample count for the disk of radius `reach` = R + ½: about one sample per
// 16 px (4 half-res texels), at least 12, at most max_samples. Sample i of N stands for the ring
// between reach·√(i/N) and reach·√((i+1)/N), equal areas π·reach²/N; sample 0's disk, the core of
// radius reach/√N, is left to the pixel's own term (dof_fast.frag, core_share).
int fast_sample_count(float reach, int max_samples) {
    return clamp(int(3.14159265 * reach * reach / 16.0), 12, max_samples);
}

// The weight of the core's sources, taken as all alike the pixel (radius r): the share of r's
// disk inside the core, (ρ_core / (r + ½))², at most 1 (then the core holds every source that
// reaches p, and their weights sum to 1). The pixel's own weight w_p is the floor
// (dof_fast.frag): a pixel sharper than the sample spacing stays sharp.
float core_share(float r, float core) {
    return min(core * core / ((r + 0.5) * (r + 0.5)), 1.0);
}
