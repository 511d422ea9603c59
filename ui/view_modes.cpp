#include "view_modes.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>

#include "studio_context.h"
#include "synth/synth.h"
#include "util/error.h"
#include "viewer_panel.h"

namespace refocus {

namespace {

Image grey_to_rgb(const Image& g, float scale = 1.0f) {
    Image out(g.width, g.height, 3);
    for (size_t i = 0; i < static_cast<size_t>(g.width) * g.height; ++i)
        for (int c = 0; c < 3; ++c)
            out.pixels[i * 3 + c] = srgb_to_linear(g.pixels[i * g.channels] * scale);
    return out;
}

Image black(StudioContext& ctx) {
    return Image(ctx.source->width(), ctx.source->height(), 3, 0.0f);
}

// The lens's gather window follows the largest radius this frame can have: the picture is the
// same as with the default bound, and small apertures render much faster.
void bound_lens_radius(PreviewLens& lens, const DepthModel& depth, int frame) {
    float lo = 1e30f, hi = -1e30f;
    auto range = [&](const Image& a, float off) {
        for (float v : a.pixels)
            if (std::isfinite(v)) lo = std::min(lo, v + off), hi = std::max(hi, v + off);
    };
    range(depth.bg_atlas, 0.0f);
    if (depth.has_fg()) range(depth.fg_atlas, depth.fg_offset[frame]);
    if (lo <= hi) {
        const double r =
            lens.aperture * std::max(std::abs(hi - lens.focus), std::abs(lo - lens.focus));
        lens.max_radius = std::clamp(std::ceil(r) + 1.0, 1.0, lens.max_radius);
    }
}

// The GLSL preview of the fit's layers at the playhead: sharp, or through the keyed lens.
Image preview_image(StudioContext& ctx, bool refocus) {
    if (!ctx.gl) throw Error("the GLSL preview is unavailable: " + ctx.gl_error);
    const FrameMaps& m = ctx.view->maps;
    const int64_t ev = ctx.edits_version();
    if (ev != ctx.edit_version) {
        // Edited atlases (paper Fig. 1): the composite pass samples them through every frame's UV.
        Image bg = ctx.doc.edits().bg.result();
        Image fg = m.fg.empty() ? Image() : ctx.doc.edits().fg.result();
        if (bg.empty()) return m.sharp;  // atlases not received yet
        ctx.gl->set_atlases(bg, fg);
        ctx.edit_version = ev;
    }
    ctx.gl->set_frame(m.uv_bg, m.uv_fg, m.alpha);
    PreviewLens lens;
    if (refocus) {
        lens = ctx.doc.focus().lens_at(ctx.frame, ctx.depth.get());
        if (ctx.depth) {
            ctx.gl->set_depth(ctx.depth->frame_depth(ctx.frame, m.uv_bg, m.uv_fg));
            bound_lens_radius(lens, *ctx.depth, ctx.frame);
        }
    }
    const double t0 = glfwGetTime();
    ctx.gl->render(lens);
    Image out = ctx.gl->read_result();  // waits for the GPU: the render's full cost
    ctx.times.last_preview_ms = (glfwGetTime() - t0) * 1000.0;
    return out;
}

Image render_input(const ViewerState&, StudioContext& ctx) {
    return ctx.source->linear(ctx.frame);
}

Image render_sharp(const ViewerState& v, StudioContext& ctx) {
    if (!ctx.view) return render_input(v, ctx);
    return preview_image(ctx, false);
}

Image render_refocused(const ViewerState& v, StudioContext& ctx) {
    if (!ctx.view) return render_input(v, ctx);
    return preview_image(ctx, ctx.depth != nullptr);  // sharp until the depth is fitted
}

Image render_split(const ViewerState& v, StudioContext& ctx) {
    Image a = v.split_a->render(v, ctx), b = v.split_b->render(v, ctx);
    if (!a.same_shape(b)) return a;
    const int cut = static_cast<int>(v.split * a.width);
    for (int y = 0; y < a.height; ++y)
        for (int x = cut; x < a.width; ++x)
            for (int c = 0; c < 3; ++c) a.at(x, y, c) = b.at(x, y, c);
    for (int y = 0; y < a.height && cut < a.width; ++y)
        for (int c = 0; c < 3; ++c) a.at(cut, y, c) = 1.0f;  // the wipe line
    return a;
}

Image render_radius(const ViewerState& v, StudioContext& ctx) {
    if (!ctx.view) return render_input(v, ctx);
    return coc_heatmap(ctx.view->radius, 12.0);
}

Image render_depth(const ViewerState&, StudioContext& ctx) {
    if (!ctx.view || !ctx.depth) return black(ctx);
    const FrameMaps& m = ctx.view->maps;
    Image g = ctx.depth->depth_map(ctx.frame, m.uv_bg, m.uv_fg, m.alpha);
    float lo = 1e30f, hi = -1e30f;
    for (float v : g.pixels) lo = std::min(lo, v), hi = std::max(hi, v);
    for (size_t i = 0; i < g.pixels.size(); ++i)
        g.pixels[i] = (g.pixels[i] - lo) / std::max(hi - lo, 1e-6f);
    return coc_heatmap(g, 1.0);
}

Image render_alpha(const ViewerState&, StudioContext& ctx) {
    if (!ctx.view || ctx.view->maps.alpha.empty()) return black(ctx);
    return grey_to_rgb(ctx.view->maps.alpha);
}

}  // namespace

const std::vector<ViewModeInfo>& view_modes() {
    // name, label, key, needs_fit, refocused, wipe, render
    static const std::vector<ViewModeInfo> modes = {
        {"input", "Input", 0, false, false, false, render_input},
        {"sharp", "Sharp", 0, true, false, false, render_sharp},
        {"refocused", "Refocused", 0, true, true, false, render_refocused},
        {"split", "Split", 0, true, false, true, render_split},
        {"radius", "Radius", 0, true, false, false, render_radius},
        {"depth", "Depth", 0, true, false, false, render_depth},
        {"alpha", "Alpha", 0, true, false, false, render_alpha},
    };
    return modes;
}

const ViewModeInfo& view_mode(const std::string& name) {
    std::string names;
    for (const ViewModeInfo& m : view_modes()) {
        if (name == m.name) return m;
        names += (names.empty() ? "" : ", ") + std::string(m.name);
    }
    throw Error("unknown view mode '" + name + "' (" + names + ")");
}

}  // namespace refocus
