#include "radius/stack_floor.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "ops/morphology.h"
#include "radius/edge_blur.h"
#include "radius/spectral_blur.h"

namespace refocus {

namespace F = torch::nn::functional;

namespace {

// Readings of the composite's absolute blur r0 binned into cells of `cell` px on the canvas.
struct FloorBins {
    int cell = 1;
    int64_t Gh = 0, Gw = 0;
    std::vector<std::vector<float>> bins;
    std::vector<float> all;
    int64_t used = 0;
};

FloorBins floor_bins(int64_t Hc, int64_t Wc, const StackCocOptions& o) {
    FloorBins b;
    const int64_t side = o.floor_cell_side > 0 ? o.floor_cell_side : std::min(Hc, Wc);
    b.cell = std::max<int>(o.spread_px, int(side / 15));
    b.Gh = (Hc + b.cell - 1) / b.cell;
    b.Gw = (Wc + b.cell - 1) / b.cell;
    b.bins.resize(b.Gh * b.Gw);
    return b;
}

// Frame t's readings of absolute radius e at (x, y): where the frame's relative radius there
// (the stack's) is rel, r0 = sqrt(e² − rel²); placed on the canvas by to_canvas_t.
void add_readings(FloorBins& b, const torch::Tensor& x, const torch::Tensor& y,
                  const torch::Tensor& e, const torch::Tensor& rel_t,
                  const torch::Tensor& to_canvas_t, const StackCocOptions& o,
                  bool near_sharpest_only = false) {
    if (e.numel() == 0) return;
    auto xi = x.to(torch::kLong), yi = y.to(torch::kLong);
    auto r_rel = rel_t.index({yi, xi});
    // The floor dominates the reading (r0 >= 0.87 e), or the frame is near its sharpest view.
    // Tiles count only near their sharpest view: under a blur read from tile spectra the stack's
    // relative readings are mostly its own error, and e² − rel² would take that error off a
    // reading (docs/method.md, Radius estimation).
    auto keep = near_sharpest_only ? r_rel < o.floor_rel_max
                                   : (r_rel < o.floor_rel_max) | (r_rel <= 0.5 * e);
    auto r0 = (e.pow(2) - r_rel.pow(2)).clamp_min(0).sqrt().masked_select(keep).contiguous();
    auto pts = torch::stack({x.masked_select(keep), y.masked_select(keep), torch::ones_like(r0)})
                   .to(torch::kFloat64);
    auto q = torch::matmul(to_canvas_t.to(torch::kFloat64), pts);
    auto cx = (q[0] / q[2]).contiguous(), cy = (q[1] / q[2]).contiguous();
    const double* px = cx.data_ptr<double>();
    const double* py = cy.data_ptr<double>();
    const float* pr = r0.data_ptr<float>();
    for (int64_t i = 0; i < r0.numel(); ++i) {
        const int64_t gx = int64_t(std::floor(px[i] / b.cell)),
                      gy = int64_t(std::floor(py[i] / b.cell));
        if (gx < 0 || gy < 0 || gx >= b.Gw || gy >= b.Gh) continue;
        b.bins[gy * b.Gw + gx].push_back(pr[i]);
        b.all.push_back(pr[i]);
        ++b.used;
    }
}

std::string fmt_px(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.1f px", v);
    return b;
}

float median_of(std::vector<float> v) {
    if (v.empty()) return 0.0f;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
}

// The floor surface [Hc,Wc] from binned readings: each cell's median where it holds at least
// min_local readings (robust to the few textures whose edges read a false blur the same way in
// every frame), a robust quadratic over the cells, held within floor_fill_cells cells of a
// measured one, the small-radius ramp, and the layer's rim. `*median` gets its median over `own`.
torch::Tensor floor_surface(FloorBins& b, int min_local, double rmax, int reach_px, bool plane,
                            int64_t Hc, int64_t Wc, const torch::Tensor& own,
                            const StackCocOptions& o, double* median) {
    const int cell = b.cell;
    const int64_t Gh = b.Gh, Gw = b.Gw;
    auto med = torch::zeros({1, 1, Gh, Gw}), has = torch::zeros({1, 1, Gh, Gw});
    for (int64_t i = 0; i < Gh * Gw; ++i) {
        auto& v = b.bins[i];
        if (v.empty() || int64_t(v.size()) < min_local) continue;
        med.view({-1})[i] = median_of(v);
        has.view({-1})[i] = 1.0f;
    }
    // The floor is a smooth surface over the layer: a quadratic in canvas coordinates fitted to
    // the cells' medians (weighted by their counts), robustly (iteratively reweighted, Tukey's
    // biweight at 4.685 MADs). Each texture reads its own bias (a panel of stripes high, of
    // glyphs low), and a cell-by-cell map turns those into a patchwork of radii that the fit
    // deconvolves into rings and garbled stripes (docs/method.md, Radius estimation). The depth
    // of a layer that is never in focus changes slowly over it; what changes fast is a focus
    // change, which the stack measures.
    std::vector<double> cu, cv, cr, cw;
    for (int64_t gy = 0; gy < Gh; ++gy)
        for (int64_t gx = 0; gx < Gw; ++gx) {
            const int64_t i = gy * Gw + gx;
            if (has.view({-1})[i].item<float>() < 0.5) continue;
            cu.push_back(((gx + 0.5) * cell) / Wc - 0.5);
            cv.push_back(((gy + 0.5) * cell) / Hc - 0.5);
            cr.push_back(med.view({-1})[i].item<float>());
            cw.push_back(std::sqrt(double(b.bins[i].size())));
        }
    const int64_t n = cr.size();
    if (n == 0) {
        *median = 0;
        return torch::zeros({Hc, Wc});
    }
    auto U = torch::tensor(cu, torch::kFloat64), V = torch::tensor(cv, torch::kFloat64);
    auto R = torch::tensor(cr, torch::kFloat64), W0 = torch::tensor(cw, torch::kFloat64);
    auto basis = [](const torch::Tensor& u, const torch::Tensor& v) {
        return torch::stack({torch::ones_like(u), u, v, u * u, u * v, v * v}, 1);
    };
    auto A = basis(U, V);
    // Quadratic, plane or constant by the number of measured cells: a quadratic through a few
    // cells (a tiny clip) can bend the floor the wrong way.
    // A plane only (`plane`) for the tile spectra's floor: a planar surface's inverse depth is
    // affine in image coordinates, and so its blur where it is never in focus (seed 001 eq. 1.12).
    const int64_t P = n >= 40 && !plane ? 6 : n >= 10 ? 3 : 1;
    A = A.narrow(1, 0, P);
    auto wts = W0.clone();
    torch::Tensor coef;
    for (int it = 0; it < 10; ++it) {
        auto sw = wts.sqrt().unsqueeze(1);
        coef = std::get<0>(torch::linalg::lstsq(A * sw, (R * wts.sqrt()).unsqueeze(1), c10::nullopt,
                                                c10::nullopt));
        auto res = R - torch::matmul(A, coef).squeeze(1);
        const double mad = std::max(0.1, res.abs().median().item<double>() * 1.4826);
        auto z = (res / (4.685 * mad)).clamp(-1, 1);
        wts = W0 * (1 - z * z).pow(2);
    }
    // How much a plane changes over reach_px: its gradient (per px) times reach_px.
    double slope_reach = 0;
    if (P == 3) {
        const double gu = coef[1].item<double>() / Wc, gv = coef[2].item<double>() / Hc;
        slope_reach = std::sqrt(gu * gu + gv * gv) * reach_px;
    }
    auto ys = (torch::arange(Hc, torch::kFloat64) + 0.5) / double(Hc) - 0.5;
    auto xs = (torch::arange(Wc, torch::kFloat64) + 0.5) / double(Wc) - 0.5;
    auto g = torch::meshgrid({ys, xs}, "ij");
    auto r0 = torch::matmul(basis(g[1].flatten(), g[0].flatten()).narrow(1, 0, P), coef)
                  .view({Hc, Wc})
                  .to(torch::kFloat32)
                  // Within the cells' own range: a surface through few cells extrapolates (a
                  // few edges reading little blur can make a floor of several px). A plane
                  // through tiles' centres (32-64 px from the border) may reach their half-size
                  // further, or the layer's outer rows read short of their blur.
                  .clamp(std::max(0.0, R.min().item<double>() - (plane ? slope_reach : 0.0)),
                         std::min(rmax, R.max().item<double>() + (plane ? slope_reach : 0.0)));
    // The surface holds where it was measured: within floor_fill_cells cells of a measured cell,
    // fading to 0 (no evidence of blur) beyond. Fewer cells leave the wall under the subject's
    // path, where few edges pass, without a floor; more overshoot on a tiny clip
    // (docs/method.md, Radius estimation).
    auto near = has;
    // A reading stands for reach_px around its place (a tile's half-size), and holds that much
    // further.
    for (int k = 0; k < o.floor_fill_cells + (reach_px + cell - 1) / cell; ++k)
        near = F::max_pool2d(near, F::MaxPool2dFuncOptions(3).stride(1).padding(1));
    auto support = F::interpolate(near, F::InterpolateFuncOptions()
                                            .size(std::vector<int64_t>{Gh * cell, Gw * cell})
                                            .mode(torch::kBilinear)
                                            .align_corners(false))
                       .narrow(2, 0, Hc)
                       .narrow(3, 0, Wc)[0][0];
    r0 = r0 * support;
    const double lo = o.floor_lo, hi = std::max(o.floor_hi, lo + 1e-3);
    r0 = torch::where(r0 >= hi, r0, ((r0 - lo) / (hi - lo)).clamp(0, 1) * hi);
    auto inside = r0.masked_select(own > 0.5);
    *median = inside.numel() ? inside.median().item<double>() : 0.0;
    // The floor covers the layer's own canvas and its rim: `own` stops contrast_window + 1 px
    // short of the canvas border, and those rows and columns would otherwise keep no floor (a
    // frame's outer rows reading a fraction of their blur).
    const int rim = o.contrast_window + 1 + o.window;
    return r0 *
           max_filter((own > 0.5).to(torch::kFloat32).view({1, 1, Hc, Wc}), rim).view({Hc, Wc});
}

}  // namespace

torch::Tensor absolute_floor(const FitData& d, const torch::Tensor& to_canvas,
                             const torch::Tensor& region, const std::vector<torch::Tensor>& rel,
                             const torch::Tensor& own, const StackCocOptions& o,
                             std::string& report, bool* spectral) {
    *spectral = false;
    const int64_t Hc = own.size(0), Wc = own.size(1), H = d.height, W = d.width;
    FloorBins edges = floor_bins(Hc, Wc, o);
    int64_t measured = 0, candidates = 0;
    // The floor is the composite's, on the canvas: a long clip's frames repeat the same readings,
    // so at most floor_frames of them, spread over the clip, are read.
    std::vector<int64_t> read;
    const int64_t n = std::min<int64_t>(d.frames, std::max(o.floor_frames, 1));
    for (int64_t i = 0; i < n; ++i)
        read.push_back(n == 1 ? 0 : (i * (d.frames - 1) + (n - 1) / 2) / (n - 1));
    // The edges tested are shared among the frames read (a frame's own cap still holds): the
    // floor's cells need tens of readings, not the 20 000 a frame a 640 px proxy offers.
    EdgeBlurOptions edge = o.edge;
    if (o.floor_edges > 0)
        edge.max_candidates = std::max<int>(
            1, std::min<int64_t>(edge.max_candidates, o.floor_edges / int64_t(read.size())));
    std::vector<torch::Tensor> lumas;
    for (int64_t t : read) {
        const auto& f = d.input[t];
        lumas.push_back(0.2126 * f[0] + 0.7152 * f[1] + 0.0722 * f[2]);
        auto allowed = region.defined() ? (region[t][0] > 0.5) : torch::ones({H, W}, torch::kBool);
        const EdgeBlurSamples e = measure_edge_blur(lumas.back(), allowed, d.blur, edge);
        measured += e.size();
        candidates += e.candidates;
        if (e.size()) add_readings(edges, e.x, e.y, e.radius, rel[t], to_canvas[t], o);
    }
    char buf[400];
    if (edges.used < o.min_edges) {
        std::snprintf(buf, sizeof buf, "%lld edges measured, %lld usable: no floor",
                      (long long)measured, (long long)edges.used);
        report = buf;
        return torch::zeros({Hc, Wc});
    }
    double floor_median = 0;
    auto r0 = floor_surface(edges, o.min_local_edges, o.edge.rmax, 0, false, Hc, Wc, own, o,
                            &floor_median);
    std::snprintf(buf, sizeof buf,
                  "%lld of %lld edges measured, %lld usable (median %.2f px), floor median %.2f px",
                  (long long)measured, (long long)candidates, (long long)edges.used,
                  double(median_of(edges.all)), floor_median);
    report = buf;
    if (floor_median <= o.spectral_from) return r0;
    // Large blur: edges read it low. A wall blurred 6-9 px carries its texture (glyphs, checkers of
    // 1-6 px) inside every profile's window, and only the edges that look narrower pass; a floor
    // that low makes the fit worse than the input (docs/method.md, Radius estimation). The
    // blur is then read from the spectra of tiles clear of the other layer (spectral_blur.h),
    // which needs a large blur to be told from texture; where they read past floor_max, their
    // floor replaces the edges'. Otherwise the edges' floor stands up to floor_max, and past it
    // there is none.
    FloorBins tiles = floor_bins(Hc, Wc, o);
    int64_t tested = 0;
    if (o.spectral) {
        for (size_t i = 0; i < read.size(); ++i) {
            const int64_t t = read[i];
            auto allowed = region.defined()
                               ? min_filter((region[t] > 0.5).to(torch::kFloat32).unsqueeze(0),
                                            o.floor_gate_clear_px)[0][0] > 0.5
                               : torch::ones({H, W}, torch::kBool);
            const SpectralBlurSamples s =
                measure_spectral_blur(lumas[i], allowed, d.blur, o.spectral_blur);
            tested += s.tiles;
            // A tile reading under floor_max contradicts the edges: a panel of checkers or a
            // sunburst, whose harmonics a small blur explains better.
            auto large = s.radius > o.floor_max;
            if (s.size())
                add_readings(tiles, s.x.masked_select(large), s.y.masked_select(large),
                             s.radius.masked_select(large), rel[t], to_canvas[t], o,
                             /*near_sharpest_only=*/true);
        }
    }
    double spectral_median = 0;
    torch::Tensor r0s;
    if (tiles.used >= o.min_tiles)
        r0s = floor_surface(tiles, o.min_local_edges, o.spectral_blur.rmax,
                            std::max(o.spectral_blur.tile_h, o.spectral_blur.tile_w) / 2, true, Hc,
                            Wc, own, o, &spectral_median);
    std::snprintf(buf, sizeof buf,
                  "; tile spectra: %lld of %lld tiles read (median %.2f px), floor median %.2f px",
                  (long long)tiles.used, (long long)tested, double(median_of(tiles.all)),
                  spectral_median);
    const std::string tiles_line = o.spectral ? std::string(buf) : std::string();
    if (o.spectral && tiles.used >= o.min_tiles && spectral_median > o.floor_max) {
        report += tiles_line + ", taken";
        *spectral = true;
        return r0s;
    }
    if (floor_median <= o.floor_max) {
        report += tiles_line + ", the edges' taken";
        return r0;
    }
    report +=
        tiles_line + ": past what isolated edges measure (" + fmt_px(o.floor_max) + "), withdrawn";
    return torch::zeros({Hc, Wc});
}

}  // namespace refocus
