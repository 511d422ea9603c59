// Plane + parallax for the fast model's background (Irani & Anandan 1996, "Parallax geometry of
// pairs of points for 3D scene analysis"; Sawhney 1994): a rigid scene under a moving camera is
// the homography of a reference plane plus, for each point, its parallax γ (inverse depth
// relative to the plane) along the direction of the camera's translation, the epipole:
//   p_t ≅ H_t·u + γ(u)·e_t.
// In atlas coordinates of frame t's pixels this is u = H_t⁻¹-mapped x + γ(u)·(a_t + b_t·(u −
// c_t)/R), one field γ for the clip and three numbers per frame, so that parallax cannot drift the
// way per-frame warps chained over a clip do.
#include <torch/torch.h>

#include <cmath>
#include <cstdio>

#include "fit/fast_model.h"
#include "fit/flow_warp.h"

namespace refocus {

namespace F = torch::nn::functional;

std::string FastModel::make_parallax(Atlas& a,
                                     const std::function<torch::Tensor(int64_t)>& region) {
    torch::NoGradGuard no_grad;
    const int64_t H = m_data.height, W = m_data.width;
    // Each frame's centre and its two unit steps mapped into the atlas: where the view is and
    // how large the atlas looks in it.
    const double cx = 0.5 * (W - 1), cy = 0.5 * (H - 1);
    auto pts = torch::tensor({cx, cy, 1.0, cx + 1, cy, 1.0, cx, cy + 1, 1.0}, torch::kFloat64)
                   .view({3, 3})
                   .t();                                          // [3,3] columns
    auto p = torch::matmul(a.to_atlas.to(torch::kFloat64), pts);  // [T,3,3]
    auto xy = p.narrow(1, 0, 2) / p.narrow(1, 2, 1);              // [T,2,3]
    auto c = xy.select(2, 0);                                     // [T,2]
    auto scale = ((xy.select(2, 1) - c).norm(2, 1) * (xy.select(2, 2) - c).norm(2, 1)).sqrt();
    auto lateral = c - c[0];                // [T,2]
    auto forward = scale / scale[0] - 1.0;  // [T]
    a.parallax_radius = 0.5 * std::sqrt(double(W * W + H * H)) * a.scale;
    auto travel = lateral.norm(2, 1) + forward.abs() * a.parallax_radius;
    const double n = travel.max().item<double>();
    if (!(n >= 0.5)) return "";  // the view barely moves: nothing to tell depths apart
    if (n / a.scale < m_opts.parallax_travel_px) {
        // Parallax is γ times the travel: under a few px of travel (a drift, focus breathing)
        // depths even 25 % off the plane part by about a px over the clip, what the residual
        // warps take, while a field fitted to it costs (synth hunt forced on: −0.13 dB).
        char line[200];
        std::snprintf(line, sizeof line,
                      "fit (fast): no plane + parallax on the background: the view travels "
                      "%.1f px (%.0f needed to tell depths apart)",
                      n / a.scale, m_opts.parallax_travel_px);
        return line;
    }
    a.epipole = torch::cat({lateral / n, (forward * (a.parallax_radius / n)).unsqueeze(1)}, 1)
                    .to(torch::kFloat32);
    a.centre = c.to(torch::kFloat32);
    const double cell = double(m_opts.parallax_cell_px) * a.scale;
    const int64_t gh = int64_t(std::ceil(a.height / cell)) + 1,
                  gw = int64_t(std::ceil(a.width / cell)) + 1;
    a.parallax = torch::zeros({1, 1, gh, gw});
    char line[320];
    int len =
        std::snprintf(line, sizeof line,
                      "fit (fast): plane + parallax on the background (a %lldx%lld field; the "
                      "view travels up to %.1f px in the atlas, its scale %.3f-%.3f of frame "
                      "0's)",
                      (long long)gw, (long long)gh, n, (forward.min().item<double>() + 1),
                      (forward.max().item<double>() + 1));
    // γ and the epipoles from the flow: a learned γ starts at 0, where a few pixels of parallax
    // are already past what the photometric gradient sees. Restoring (no region), the checkpoint
    // says whether the fit kept the field (load_state).
    if (!region) return line;
    ParallaxInit init;
    if (m_data.flow_fwd.defined() && m_data.flow_valid.defined())
        init = parallax_from_flow(a.to_atlas, m_data.flow_fwd, m_data.flow_valid, region, a.epipole,
                                  a.centre, a.parallax_radius, a.width, a.height, gh, gw,
                                  m_opts.parallax_evidence, 150, 4, m_opts.parallax_homography);
    const double held = init.held_gain();
    if (m_opts.parallax_evidence > 0 && !(held >= m_opts.parallax_evidence)) {
        a.parallax = torch::Tensor();
        a.epipole = torch::Tensor();
        a.centre = torch::Tensor();
        std::string why = m_data.flow_fwd.defined()
                              ? "too few frame pairs of flow to test a depth field"
                              : "no optical flow to test a depth field";
        if (std::isfinite(held))
            why = "fitted to half the frame pairs, the flow's field predicts the other half " +
                  std::to_string(std::lround(100 * std::abs(held))) +
                  (held < 0 ? "% worse" : "% better") + " (" +
                  std::to_string(std::lround(100 * m_opts.parallax_evidence)) +
                  "% needed): no depth the pairs share";
        std::snprintf(line, sizeof line,
                      "fit (fast): no plane + parallax on the background (the view travels up to "
                      "%.1f px): %s",
                      n, why.c_str());
        return line;
    }
    if (init.points > 0 && init.after_px < init.before_px) {
        a.parallax = init.parallax;
        a.epipole = init.epipole;
        if (init.correction.defined())
            a.to_atlas =
                torch::matmul(init.correction, a.to_atlas.to(torch::kFloat64)).to(torch::kFloat32);
        std::snprintf(line + len, sizeof line - len,
                      ": from the flow (%lld correspondences), frames disagree by %.2f px "
                      "through the homographies, %.2f px with it; half the pairs predict the "
                      "other half %.0f%% better",
                      (long long)init.points, init.before_px, init.after_px, 100 * held);
    }
    return line;
}

torch::Tensor FastModel::add_parallax(const Atlas& a, const torch::Tensor& idx,
                                      const torch::Tensor& px) const {
    if (!a.parallax.defined()) return px;
    const int64_t B = px.size(0);
    // γ read where the homography (and residual warp) put the pixel: one fixed-point step of the
    // implicit u = u0 + γ(u)·d, exact where γ is locally constant.
    auto grid = to_grid(a, px.permute({0, 2, 3, 1}));
    auto g = F::grid_sample(a.parallax.expand({B, 1, a.parallax.size(2), a.parallax.size(3)}), grid,
                            F::GridSampleFuncOptions()
                                .mode(torch::kBilinear)
                                .padding_mode(torch::kBorder)
                                .align_corners(false));  // [B,1,h,w]
    auto e = a.epipole.index_select(0, idx);             // [B,3]
    auto c = a.centre.index_select(0, idx).view({B, 2, 1, 1});
    auto dir = e.narrow(1, 0, 2).view({B, 2, 1, 1}) +
               e.narrow(1, 2, 1).view({B, 1, 1, 1}) * (px - c) / a.parallax_radius;
    return px + g * dir;
}

torch::Tensor FastModel::parallax_bg() {
    if (!m_bg.parallax.defined()) return {};
    torch::NoGradGuard no_grad;
    return F::interpolate(m_bg.parallax.detach(),
                          F::InterpolateFuncOptions()
                              .size(std::vector<int64_t>{m_bg.height, m_bg.width})
                              .mode(torch::kBilinear)
                              .align_corners(false))[0];
}

torch::Tensor FastModel::parallax_smoothness(const torch::Tensor& g) {
    auto dx = g.narrow(3, 1, g.size(3) - 1) - g.narrow(3, 0, g.size(3) - 1);
    auto dy = g.narrow(2, 1, g.size(2) - 1) - g.narrow(2, 0, g.size(2) - 1);
    return dx.pow(2).mean() + dy.pow(2).mean() + 1e-3 * g.pow(2).mean();
}

}  // namespace refocus
