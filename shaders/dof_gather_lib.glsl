// The exact scatter-as-gather of one layer at one pixel (dof.frag's loop, shared with the fast
// path's small-radius tiles, which must give the same bits). Needs preview_lib.glsl first.
//   w(p, q) = k(r_q − ρ(p − q))·clamp(r_q − ρ(p − q) + ½, 0, 1) / K(r_q)   (paper eq. 2 kernel)
//   → (F̂, Â) = (Σ_q w·a_q·c'_q, Σ_q w·a_q) / Σ_q w over the window floor(rwin + ½).
// prep0_tx: (a·c', r); prep1_tx: (a, 1/K); shape_tx: ρ(o) at o = p − q, centre (window, window).
// CPU twin: gather (engine/render/preview.cpp).
vec4 gather_exact(sampler2D prep0_tx, sampler2D prep1_tx, sampler2D shape_tx, ivec2 p, float rwin,
                  int window, float beta) {
    ivec2 n = textureSize(prep0_tx, 0);
    int half_w = int(floor(rwin + 0.5));
    if (half_w == 0)  // early pass-through: nothing within reach is blurred
        return vec4(texelFetch(prep0_tx, p, 0).rgb, texelFetch(prep1_tx, p, 0).r);
    float sr = 0.0, sg = 0.0, sb = 0.0, sa = 0.0, sw = 0.0;
    // Taps with dx² + dy² ≥ (R + ½)² add exactly 0 (ρ_n ≥ ρ): skip them per row (+1 px against
    // rounding; the twin need not skip the same ones).
    float reach2 = (rwin + 0.5) * (rwin + 0.5);
    for (int dy = -half_w; dy <= half_w; ++dy) {
        int qy = p.y + dy;
        if (qy < 0 || qy >= n.y) continue;
        int span = min(half_w, int(sqrt(max(reach2 - float(dy * dy), 0.0))) + 1);
        for (int dx = -span; dx <= span; ++dx) {
            int qx = p.x + dx;
            if (qx < 0 || qx >= n.x) continue;
            vec4 p0 = texelFetch(prep0_tx, ivec2(qx, qy), 0);
            vec2 p1 = texelFetch(prep1_tx, ivec2(qx, qy), 0).rg;
            float rho = texelFetch(shape_tx, ivec2(window - dx, window - dy), 0).r;
            float rq = p0.a;
            float edge = rq - rho + 0.5;
            if (edge <= 0.0) continue;
            float wgt = disk_kernel(rq - rho, beta) * min(edge, 1.0) * p1.g;
            sr += wgt * p0.r;
            sg += wgt * p0.g;
            sb += wgt * p0.b;
            sa += wgt * p1.r;
            sw += wgt;
        }
    }
    return vec4(sr / sw, sg / sw, sb / sw, sa / sw);
}
