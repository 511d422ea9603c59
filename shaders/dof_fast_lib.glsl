// Shared by the fast depth-of-field passes (dof_fast_*.frag, dof_sprite.*). Needs
// preview_lib.glsl first. The fast path approximates dof.frag's exact gather; see
// docs/method.md ("The preview's depth of field").

// ρ_n(o) = |o|·cos(φ' − π/n)/cos(π/n), φ' the angle of o from a vertex modulo 2π/n: the polygon
// distance of preview_shape_table (= r on the polygon of circumradius r), computed in place.
float shape_rho(vec2 o, int blades, float rotation) {
    float rho = length(o);
    if (blades < 3 || rho == 0.0) return rho;
    float n = float(blades);
    float sector = 6.28318530718 / n;
    float phi = atan(o.y, o.x) - rotation;
    float local = phi - sector * floor(phi / sector);
    return rho * cos(local - 3.14159265359 / n) / cos(3.14159265359 / n);
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
