#include "view_modes.h"

#include <algorithm>
#include <cmath>

#include "synth/synth.h"
#include "util/error.h"

namespace refocus {

namespace {

Image grey_to_rgb(const Image& g, float scale = 1.0f) {
    Image out(g.width, g.height, 3);
    for (size_t i = 0; i < static_cast<size_t>(g.width) * g.height; ++i)
        for (int c = 0; c < 3; ++c)
            out.pixels[i * 3 + c] = srgb_to_linear(g.pixels[i * g.channels] * scale);
    return out;
}

Image black(const ModeInput& in) {
    return Image(in.input.width, in.input.height, 3, 0.0f);
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

// The fit's layers at the frame: sharp, or through the keyed lens (radii in px scale with the
// picture).
Image preview_image(const ModeInput& in, bool refocus) {
    const FrameMaps& m = in.view->maps;
    const ViewScene& s = in.scene;
    if (!refocus || !s.depth) return in.preview.render(m, s.edits, nullptr, PreviewLens{});
    PreviewLens lens = s.focus.lens_at(in.frame, s.depth.get());
    bound_lens_radius(lens, *s.depth, in.frame);
    lens.aperture *= in.scale;
    lens.max_radius = std::max(1.0, std::ceil(lens.max_radius * in.scale));
    const PreviewDepth d = s.depth->frame_depth(in.frame, m.uv_bg, m.uv_fg);
    return in.preview.render(m, s.edits, &d, lens);
}

Image render_input(const ModeInput& in) {
    return in.input;
}

Image render_sharp(const ModeInput& in) {
    return in.view ? preview_image(in, false) : in.input;
}

Image render_refocused(const ModeInput& in) {
    return in.view ? preview_image(in, true) : in.input;  // sharp until the depth is fitted
}

Image render_radius(const ModeInput& in) {
    return in.view ? coc_heatmap(in.view->radius, 12.0 * in.scale) : in.input;
}

Image render_depth(const ModeInput& in) {
    if (!in.view || !in.scene.depth) return black(in);
    const FrameMaps& m = in.view->maps;
    Image g = in.scene.depth->depth_map(in.frame, m.uv_bg, m.uv_fg, m.alpha);
    float lo = 1e30f, hi = -1e30f;
    for (float v : g.pixels) lo = std::min(lo, v), hi = std::max(hi, v);
    for (size_t i = 0; i < g.pixels.size(); ++i)
        g.pixels[i] = (g.pixels[i] - lo) / std::max(hi - lo, 1e-6f);
    return coc_heatmap(g, 1.0);
}

// The shot in grey, tinted green where the sharp plate comes from the fit and red where the fit
// cannot explain the region, or no frame saw it sharp, and the plate falls back to the shot;
// grey stays grey where nothing is blurred (the plate is the shot, and needs nothing).
// docs/method.md, Confidence and fallback.
Image render_confidence(const ModeInput& in) {
    if (!in.view || in.view->confidence.empty()) return in.input;
    const Image& c = in.view->confidence;
    const Image& src = in.input;
    Image out(src.width, src.height, 3);
    const size_t n = static_cast<size_t>(src.width) * src.height;
    const float sx = float(c.width) / src.width, sy = float(c.height) / src.height;
    for (size_t i = 0; i < n; ++i) {
        const int x = static_cast<int>(i % src.width), y = static_cast<int>(i / src.width);
        const size_t j = static_cast<size_t>(std::min(c.height - 1, int(y * sy))) * c.width +
                         std::min(c.width - 1, int(x * sx));
        const float* p = &src.pixels[i * src.channels];
        const float lum = linear_to_srgb(0.2126f * p[0] + 0.7152f * p[1] + 0.0722f * p[2]);
        const float k = c.pixels[j * c.channels], w = c.pixels[j * c.channels + 1];
        const float base = 0.45f * lum, red = 1.0f - k, green = w;
        const float rgb[3] = {base + 0.55f * red, base + 0.45f * green * (1 - red), base};
        for (int ch = 0; ch < 3; ++ch)
            out.pixels[i * 3 + ch] = srgb_to_linear(std::clamp(rgb[ch], 0.0f, 1.0f));
    }
    return out;
}

Image render_alpha(const ModeInput& in) {
    if (!in.view || in.view->maps.alpha.empty()) return black(in);
    return grey_to_rgb(in.view->maps.alpha);
}

}  // namespace

const std::vector<ViewModeInfo>& view_modes() {
    // name, label, tooltip, key, needs_fit, refocused, wipe, render
    static const std::vector<ViewModeInfo> modes = {
        {"input", "Input", "The clip as it was shot", 0, false, false, false, render_input},
        {"sharp", "Sharp", "The all-in-focus plate the fit recovered", 0, true, false, false,
         render_sharp},
        {"refocused", "Refocused", "The sharp plate through the keyed lens (Focus tab)", 0, true,
         true, false, render_refocused},
        {"split", "Split", "Two modes side by side; drag the line or the wipe slider", 0, true,
         false, true, nullptr},
        {"radius", "Radius", "The blur radius the fit explains each pixel with (px)", 0, true,
         false, false, render_radius},
        {"depth", "Depth", "The fitted inverse depth, near is bright", 0, true, false, false,
         render_depth},
        {"alpha", "Alpha", "The foreground layer's matte", 0, true, false, false, render_alpha},
        {"confidence", "Confidence",
         "Green: the sharp plate comes from the fit. Red: the fit cannot explain the region, or "
         "no frame saw it sharp, and the plate falls back to the shot. Grey: nothing is blurred "
         "there; the plate is the shot",
         0, true, false, false, render_confidence},
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

int view_mode_index(const ViewModeInfo& m) {
    return static_cast<int>(&m - view_modes().data());
}

}  // namespace refocus
