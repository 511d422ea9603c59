#include "fit/fit_setup.h"

#include <torch/torch.h>

#include <malloc.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>

#include <nlohmann/json.hpp>

#include "model/atlas_geometry.h"
#include "fit/kept_clip.h"
#include "radius/stack_coc.h"
#include "io/tensor_image.h"
#include "io/image_file.h"
#include "ops/lens_blur.h"
#include "prepare/noise.h"
#include "prepare/prepare.h"
#include "prepare/proxy.h"
#include "util/mapped.h"
#include "util/debug.h"
#include "util/error.h"
#include "util/threads.h"
#include "util/timing.h"

namespace refocus {

namespace {

std::string fmt2(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.2f", v);
    return b;
}

// kernel_radius_for_coc over the maps' range, tabulated every 0.05 px and read linearly.
std::function<double(double)> coc_to_kernel_table(const std::vector<Image>& maps,
                                                  const LensBlurParams& p) {
    float mx = 0;
    for (const Image& m : maps)
        for (float v : m.pixels) mx = std::max(mx, v);
    constexpr double step = 0.05;
    auto table = std::make_shared<std::vector<double>>();
    for (int i = 0; i * step <= mx + 2 * step; ++i)
        table->push_back(kernel_radius_for_coc(i * step, p));
    return [table](double c) {
        const double u = std::max(0.0, c / step);
        const size_t i = std::min(size_t(u), table->size() - 2);
        const double f = std::min(1.0, u - double(i));
        return (*table)[i] * (1 - f) + (*table)[i + 1] * f;
    };
}

// The median of a clip-sized array from about a million of its values, evenly strided (the
// whole array's sort would be a clip-sized temporary).
float sampled_median(const torch::Tensor& x) {
    const int64_t n = x.numel(), step = std::max<int64_t>(1, n / (1 << 20));
    return x.reshape({-1}).slice(0, 0, n, step).median().item<float>();
}

// The focal-stack radius (slow to compute) is cached in prep/ beside what it was computed
// from: prep/stack_coc_%04d.exr and prep/stack_coc.json (written last) holding a key of its
// inputs (prepare.json's content, the layer decision). Opening a fitted project, exporting and
// the studio then reuse it; a new prepare or another decision recomputes it.
// The radius.* settings shape the estimate: the key holds those the user set ("/absolute" is
// the default estimate's key, kept so that existing caches stay valid).
std::string stack_key(const Project& project, const FitData& d, const FitSetupOptions& opts) {
    const std::string settings_key = "/absolute" + opts.settings.key("radius.");
    const std::string prep = read_text_file(fs::path(prepare_dir(project)) / "prepare.json");
    // The radius is measured in the kernel's units: a pillbox's differs from the disk's.
    return std::to_string(std::hash<std::string>{}(prep)) + (d.has_subject ? "/2" : "/1") +
           (d.static_camera ? "/static" : "/moving") +
           (d.blur.kernel == BlurKernel::Pillbox ? "/pillbox" : "") + "/v14" + settings_key;
}

fs::path stack_frame_path(const Project& project, int t) {
    return fs::path(prepare_dir(project)) / format_pattern("stack_coc_%04d.exr", t);
}

// One frame of the estimate at the fit's size: maps made on a proxy are scaled up bilinearly and
// by the proxy's scale (radii are lengths).
torch::Tensor radius_at_size(const torch::Tensor& r, int64_t H, int64_t W, double scale) {
    namespace F = torch::nn::functional;
    if (r.size(0) == H && r.size(1) == W) return r;
    return F::interpolate(r.view({1, 1, r.size(0), r.size(1)}),
                          F::InterpolateFuncOptions()
                              .size(std::vector<int64_t>{H, W})
                              .mode(torch::kBilinear)
                              .align_corners(false))[0][0]
        .mul(scale)
        .clamp_min(0);
}

// The cache holds the maps as estimated (on the proxy where there is one, with its scale).
torch::Tensor load_stack_radius(const Project& project, const FitData& d, const std::string& key,
                                double& fixed_focus_share) {
    const fs::path meta = fs::path(prepare_dir(project)) / "stack_coc.json";
    try {
        if (!fs::exists(meta)) return {};
        const auto j = nlohmann::json::parse(read_text_file(meta));
        if (j.value("key", "") != key) return {};
        fixed_focus_share = j.value("fixed_focus_share", 0.0);
        const double scale = j.value("scale", 1.0);
        const int w = j.value("width", d.width), h = j.value("height", d.height);
        torch::Tensor maps = d.clip_array({d.frames, d.height, d.width}, "radius");
        for (int t = 0; t < d.frames; ++t) {
            Image m = read_image_file(stack_frame_path(project, t).string(), false).image;
            if (m.width != w || m.height != h || m.channels != 1) return {};
            maps[t].copy_(radius_at_size(image_to_tensor(m)[0], d.height, d.width, scale));
        }
        return maps;
    } catch (const std::exception&) {
        return {};  // a damaged cache is recomputed
    }
}

void save_stack_radius(const Project& project, const torch::Tensor& radius, const std::string& key,
                       double fixed_focus_share, double scale) {
    // A frame's file on each core: encoding a file is serial.
    for_each_on_threads(int(radius.size(0)), 0, [&](int t, int) {
        write_image_file(stack_frame_path(project, t).string(),
                         tensor_to_image(radius[t].contiguous()), PixelFormat::ExrFloat, false);
    });
    write_file_atomic(fs::path(prepare_dir(project)) / "stack_coc.json",
                      nlohmann::json{{"key", key},
                                     {"frames", radius.size(0)},
                                     {"width", radius.size(2)},
                                     {"height", radius.size(1)},
                                     {"scale", scale},
                                     {"fixed_focus_share", fixed_focus_share}}
                          .dump(2));
}

// [T,3,3] float64 frame → reference homographies. A locked-off camera maps every frame onto the
// reference exactly: the estimated homographies' sub-pixel noise would only add flicker.
torch::Tensor homography_stack(const CameraMotion& motion, bool static_camera) {
    std::vector<torch::Tensor> hs;
    for (const auto& h : motion.to_reference)
        hs.push_back(static_camera ? torch::eye(3, torch::kFloat64)
                                   : torch::tensor(std::vector<double>(h.m.begin(), h.m.end()),
                                                   torch::kFloat64)
                                         .view({3, 3}));
    return torch::stack(hs);
}

// The focal-stack radius (stack_coc.h) of `d` estimated on its proxy (`small`, the motion
// prepared there), at the proxy's size: its cost falls with the square of the scale twice over
// (pixels, and the taps of blurs that shrink with them).
torch::Tensor stack_radius_on_proxy(const FitData& d, const std::vector<Image>& small,
                                    const CameraMotion& motion, const ProxySize& px,
                                    const StackCocOptions& so, StackCocReport* report) {
    namespace F = torch::nn::functional;
    FitData p;
    p.frames = d.frames, p.height = px.height, p.width = px.width;
    p.input = stack_images(small);
    p.blur = d.blur;
    p.static_camera = d.static_camera;
    p.has_subject = d.has_subject;
    if (d.mask.defined())
        p.mask = F::interpolate(d.mask, F::InterpolateFuncOptions()
                                            .size(std::vector<int64_t>{px.height, px.width})
                                            .mode(torch::kArea))
                     .contiguous();
    p.to_ref = homography_stack(motion, d.static_camera);
    return estimate_radius_from_stack(p, so, report);
}

}  // namespace

std::string choose_atlas_scale(FitData& d, bool radius_given, double forced) {
    // A 1x atlas resampled to a frame's sub-pixel position loses the in-focus detail the frame
    // held: fine texture sits above what a 1x grid carries when shifted. Frames that a moving
    // camera saw at many sub-pixel phases resolve it on a 2x atlas, as multi-frame
    // super-resolution does. A static camera sees each texel at one phase (nothing to resolve;
    // the 2x grid only trains slower), and what no frame saw in focus has no detail to resolve.
    // Super-resolution needs the blur right, though: a radius estimated relative to each point's
    // sharpest view errs differently in each frame, and the finer grid fits those errors. So 2x
    // is for radius maps given with --coc (a depth-derived or measured defocus), and for an
    // estimate that holds over the clip: where focus never changed, the radius is the absolute
    // floor, one smooth surface that every frame shares (docs/method.md, Atlas scale).
    torch::NoGradGuard g;
    // Counted frame by frame: a long clip's whole-array comparison is a clip-sized temporary.
    int64_t sharp = 0;
    for (int64_t t = 0; t < d.frames; ++t) sharp += (d.radius[t] < 1.5).sum().item<int64_t>();
    const double in_focus = double(sharp) / double(std::max<int64_t>(d.radius.numel(), 1));
    const double texels = 4.0 * d.height * d.width;
    std::string why;
    d.atlas_scale = 1;
    if (!radius_given && d.fixed_focus_share < 0.8) {
        why = "radius estimated from the clip, held by the fixed-focus floor on " +
              std::to_string(int(std::lround(100 * d.fixed_focus_share))) +
              "% of the wall (2x needs 80%): a finer atlas would fit its errors";
    } else if (d.static_camera) {
        why = "static camera: each atlas pixel is seen at one sub-pixel phase";
    } else if (in_focus < 0.05) {
        why = "no frame shows much in focus (" + fmt2(100 * in_focus) + "% of pixels under 1.5 px)";
    } else if (texels > 8e6) {
        why = "a 2x atlas would hold over 8 Mpx";
    } else {
        d.atlas_scale = 2;
        why = "moving camera, " + fmt2(100 * in_focus) + "% of pixels in focus";
    }
    if (forced > 0) {
        d.atlas_scale = std::clamp(forced, 1.0, 4.0);
        why = "the fast.atlas_scale setting";
    }
    return "fit (fast): atlas at " +
           std::string(d.atlas_scale == 1   ? "1"
                       : d.atlas_scale == 2 ? "2"
                                            : fmt2(d.atlas_scale)) +
           "x the frame's resolution (" + why + ")";
}

LensBlurParams fit_kernel_params(const std::string& kernel) {
    // Which kernel the fit reblurs with. A lens's defocus (and the synth clips' aperture
    // renderer) is a uniform disk, which the pillbox matches more closely than the paper's disk
    // (β = 2), and fits with it score higher (docs/method.md, Lens blur kernel).
    LensBlurParams p;
    if (kernel == "pillbox") {
        p.kernel = BlurKernel::Pillbox;
    } else if (kernel != "disk") {
        throw Error("fit: unknown kernel '" + kernel + "' (use pillbox or disk)");
    }
    return p;
}

namespace {

// Freed proxies and preparation results are many frame-sized blocks in malloc's heap, which it
// keeps resident unless asked to return them: a long clip's are GBs.
void release_freed_memory() {
#ifdef __GLIBC__
    malloc_trim(0);
#endif
}

// The clip's noise as the project stores it (measured now where it does not).
void read_noise(const Project& project, FitData& d, PrepareLog& log) {
    const bool stored = project.sections.contains("noise");
    const NoiseEstimate noise = project_noise(project);
    d.noise_levels = noise.measured() ? noise.mean() : -1.0;
    log.info("noise: " + noise.describe() + (stored ? "" : " (measured now)"));
}

void log_kernel(const FitSetupOptions& opts, PrepareLog& log) {
    log.info("kernel: " + opts.kernel +
             (opts.kernel == "pillbox" ? " (a uniform disk, seed 001 eq. 1.13)"
                                       : " (the paper's eq. 2, beta = 2)"));
}

// What every opening ends with: the atlas scale and the log's summary.
std::shared_ptr<FitData> finish_fit_data(std::shared_ptr<FitData> d, const FitSetupOptions& opts,
                                         PrepareLog& log) {
    log.info(choose_atlas_scale(*d, d->radius_given, opts.atlas_scale));
    log.info(std::string("fit: ") +
             (d->static_camera ? "static camera, no learned background warp"
                               : "moving camera, learned residual warp") +
             ", " +
             (d->has_subject ? "two layers (moving subject)" : "one layer (no moving subject)"));
    return d;
}

}  // namespace

std::shared_ptr<FitData> build_fit_data(const Project& project, const FitSetupOptions& opts,
                                        PrepareLog& log) {
    // Progress: the steps' shares are the sample clip's timings (320x180, 30 frames, radius
    // from the focal stack: 70% of the time), rough for any other clip.
    log.stage("reading the frames", 0.0, 0.03);
    StageClock clock;  // --debug timing: the clip's data, stage by stage
    clock.next("data: reading the frames", "reading the frames");
    const int64_t T = project.frames, H = project.height, W = project.width;
    auto d = std::make_shared<FitData>();
    d->frames = int(T), d->height = int(H), d->width = int(W);
    // A clip whose frames exceed the budget keeps its per-frame arrays in file mappings
    // (util/mapped.h) in the project's work/ folder: its memory then does not grow with it.
    const double frames_mb = double(T) * 3 * H * W * sizeof(float) / (1 << 20);
    if (frames_mb > opts.memory_mb) {
        d->mapped_dir = project.dir / "work";
        start_mapped_trimmer();
        log.info("memory: the clip's frames take " + std::to_string(int(frames_mb)) +
                 " MB (over fit.memory_mb); its per-frame arrays stream through " +
                 d->mapped_dir.string());
        if (opts.clip_cache) d->cache_dir = project.dir / "work" / "clip";
    }
    d->blur = fit_kernel_params(opts.kernel);
    d->radius_given = !opts.coc_path.empty();
    // What the rest of this function makes, a long clip's last command kept (model/clip_cache.h).
    if (!d->cache_dir.empty() && !opts.force_prepare && has_prepare(project)) {
        d->cache_key = clip_cache_key(project, opts);
        clock.next("data: the kept arrays", "opening the clip's kept arrays");
        if (open_kept_clip(*d)) {
            read_noise(project, *d, log);
            log.info("data: the clip's arrays as the last command kept them in " +
                     d->cache_dir.string() + " (fit.clip_cache)");
            log_kernel(opts, log);
            return finish_fit_data(d, opts, log);
        }
        clock.next("data: reading the frames", "reading the frames");
    }
    // Preparation runs on proxies of large frames (proxy.h): `small` holds them, and the
    // full-size frames go straight to the fit's input.
    const ProxySize px = proxy_size(project.width, project.height, opts.proxy_width);
    std::vector<Image> frames(px.active() ? 0 : T), small(px.active() ? T : 0);
    d->input = d->clip_array({T, 3, H, W}, "input");
    // Two frames at a time: decoding a cached frame and scaling it down take one core each.
    // Each frame is checked finite as it is read (check_finite then need not read the clip).
    std::vector<char> finite(T, 0);
    at::parallel_for(0, T, 1, [&](int64_t t0, int64_t t1) {
        for (int64_t t = t0; t < t1; ++t) {
            Image f = project.read_frame(int(t));
            d->input[t].copy_(image_to_tensor(f));
            finite[t] = finite_frame(d->input[t]);
            if (px.active())
                small[t] = resize_image(f, px.width, px.height);
            else
                frames[t] = std::move(f);
        }
    });
    d->input_finite = std::all_of(finite.begin(), finite.end(), [](char ok) { return ok; });
    debug_memory("setup: frames read");
    read_noise(project, *d, log);
    if (px.active())
        log.info("prepare: on " + std::to_string(px.width) + "x" + std::to_string(px.height) +
                 " proxies (prepare.proxy_width), scaled up to " + std::to_string(project.width) +
                 "x" + std::to_string(project.height));

    // The radius comes from the clip as a focal stack unless maps are given or the clip is too
    // short for one: the preparation's per-frame estimate is then neither made nor scaled up.
    const bool stack_radius = opts.coc_path.empty() && T >= 3 && !opts.single_image_coc;
    PrepareResult prep;
    bool reuse = !opts.force_prepare && has_prepare(project);
    if (reuse) {
        log.stage("loading the preparation", 0.03, 0.2);
        clock.next("data: loading the preparation", "loading the preparation");
        prep = load_prepare(project);
        // Reuse only what was prepared for the same masks, at the same size, and with a radius
        // estimate if needed.
        const std::string want_masks = opts.mask_path.empty() ? "auto" : opts.mask_path;
        if (prep.mask_source != want_masks ||
            (opts.coc_path.empty() && !stack_radius && prep.coc.empty()) ||
            prep.width != px.width || prep.height != px.height)
            reuse = false;
        else
            log.info("prepare: reusing " + prepare_dir(project));
    }
    if (!reuse) {
        PrepareOptions po;
        // Defocus changes move features by up to ~1–2 px with no camera motion at all, so
        // "static" allows that much (docs/method.md, Preparation).
        po.motion.static_max_px = 2.0;
        po.mask_path = opts.mask_path;
        po.estimate_coc = opts.coc_path.empty() && !stack_radius;
        po.full_width = project.width, po.full_height = project.height;
        // The flow's files are written while the masks are made (save_prepare then skips them).
        const int prep_w = px.active() ? px.width : int(W),
                  prep_h = px.active() ? px.height : int(H);
        po.flow_ready = [&](const ClipFlow& flow) {
            save_prepare_flow(project, flow, prep_w, prep_h);
        };
        log.set_span(0.03, 0.2);
        clock.next("data: preparing", "preparing the clip");
        prep = prepare_clip(px.active() ? small : frames, po, log);
        log.set_span(0.0, 1.0);
        log.stage("saving the preparation", 0.2, 0.23);
        save_prepare(project, prep, true);
        // The masks as stored (8-bit): the subject's track and atlas box are computed from them,
        // and a reopened project (export, the studio, --resume) must rebuild the same model.
        for (Image& m : prep.masks)
            for (float& v : m.pixels) v = std::round(std::clamp(v, 0.0f, 1.0f) * 255.0f) / 255.0f;
    }
    std::vector<Image>().swap(frames);  // prepared: the fit reads d->input
    // The fit reads the forward flow only (the backward one served its consistency check).
    std::vector<Image>().swap(prep.flow.bwd);
    std::vector<Image>().swap(prep.flow.bwd_valid);
    release_freed_memory();
    debug_memory("setup: prepared");
    log.stage("radius maps", 0.23, 0.92);
    clock.next("data: radius and flow at full size", "the radius and the flow at full size");
    log_kernel(opts, log);
    std::vector<Image> radius;
    if (!opts.coc_path.empty()) {
        radius = load_coc_maps(opts.coc_path, project.frames, project.width, project.height);
        // The maps hold circles of confusion (a thin lens's uniform disk, as the synth clips'
        // passes or a depth-derived map); the fit's kernel spreads light differently (the
        // paper's disk is softer), so each radius becomes the kernel radius with the same second
        // moment on the pixel grid (docs/method.md, Lens blur kernel).
        const auto table = coc_to_kernel_table(radius, d->blur);  // the fit's kernel
        for (Image& r : radius)
            for (float& v : r.pixels) v = float(table(v));
        log.info("radius: given per frame by " + opts.coc_path + " (circles of confusion; as the " +
                 "kernel's radius, 3 px is " + fmt2(kernel_radius_for_coc(3.0, d->blur)) +
                 ", 7 px is " + fmt2(kernel_radius_for_coc(7.0, d->blur)) + ")");
    }
    // The preparation's results at full size, frame by frame (scaled up from the proxy).
    if (!stack_radius) {
        d->radius = d->clip_array({T, H, W}, "radius");
        for (int t = 0; t < T && (!radius.empty() || !prep.coc.empty()); ++t)
            d->radius[t].copy_(
                image_to_tensor(radius.empty() ? scale_radius(prep.coc[t], W, H) : radius[t])[0]);
    }
    radius.clear();
    std::vector<Image>().swap(prep.coc);  // each is at full size in d->radius now
    d->static_camera = prep.decisions.static_camera;
    d->to_ref = homography_stack(scale_motion(prep.motion, px.sx, px.sy), d->static_camera);
    if (!prep.flow.fwd.empty()) {
        d->flow_fwd = d->clip_array({T - 1, 2, H, W}, "flow_fwd");
        d->flow_valid = d->clip_array({T - 1, 1, H, W}, "flow_valid");
        at::parallel_for(0, T - 1, 1, [&](int64_t t0, int64_t t1) {
            for (int64_t t = t0; t < t1; ++t) {
                d->flow_fwd[t].copy_(image_to_tensor(scale_flow(prep.flow.fwd[t], W, H)));
                d->flow_valid[t].copy_(image_to_tensor(scale_binary(prep.flow.fwd_valid[t], W, H)));
            }
        });
    }
    prep.flow = ClipFlow();  // at full size in d->flow_*: a long clip's flow is GBs
    debug_memory("setup: radius and flow scaled up");
    clock.next("data: the masks", "the subject's masks");
    d->has_subject = prep.decisions.has_subject && !prep.masks.empty();
    if (d->has_subject && opts.mask_path.empty()) {
        // Automatic masks threshold the flow residual, and a focus change alone makes edges
        // "move" (a different patch every frame). A subject moves coherently: its mask centre
        // travels a short way from frame to frame. If the centre jumps (median step over 4% of
        // the diagonal), the masks are defocus noise: one layer.
        std::vector<std::pair<double, double>> c;
        for (const auto& m : prep.masks) {
            double sx = 0, sy = 0, sw = 0;
            for (int y = 0; y < m.height; ++y)
                for (int x = 0; x < m.width; ++x) {
                    const double w = m.at(x, y, 0);
                    sx += w * x, sy += w * y, sw += w;
                }
            if (sw >= 4) c.emplace_back(sx / sw, sy / sw);
        }
        std::vector<double> steps;
        for (size_t i = 1; i < c.size(); ++i)
            steps.push_back(std::hypot(c[i].first - c[i - 1].first, c[i].second - c[i - 1].second));
        const double diag = std::hypot(prep.width, prep.height);  // the masks' own size
        double median = 0;
        if (!steps.empty()) {
            std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
            median = steps[steps.size() / 2];
        }
        if (median > 0.04 * diag) {
            d->has_subject = false;
            char line[200];
            std::snprintf(line, sizeof line,
                          "automatic masks are incoherent (their centre jumps %.1f px per frame, "
                          "median): focus changes, not a subject; one layer (use --mask to "
                          "separate a subject)",
                          median);
            log.info(line);
        }
    }
    if (d->has_subject) {
        // A roto matte is kept as drawn, at full size; automatic masks are scaled up.
        const std::vector<Image> roto =
            px.active() && !opts.mask_path.empty()
                ? load_masks(opts.mask_path, project.frames, project.width, project.height)
                : std::vector<Image>{};
        d->mask = d->clip_array({T, 1, H, W}, "mask");
        for (int t = 0; t < T; ++t)
            d->mask[t].copy_(
                image_to_tensor(roto.empty() ? resize_image(prep.masks[t], W, H) : roto[t]));
        if (prep.mask_source == "auto") {  // a roto matte is kept as given
            d->mask_as_stored = d->mask;
            clock.next("data: cleaning the masks", "cleaning the subject's masks");
            log.info(clean_subject_masks(*d));
        }
    }
    std::vector<Image>().swap(prep.masks);
    release_freed_memory();  // before the focal stack's working set
    if (opts.coc_path.empty()) {
        if (stack_radius) {
            clock.next("data: the focal-stack radius", "the focal-stack radius");
            const std::string key = stack_key(project, *d, opts);
            torch::Tensor cached = load_stack_radius(project, *d, key, d->fixed_focus_share);
            if (cached.defined()) {
                d->radius = cached;
            } else {
                StackCocReport report;
                StackCocOptions so;
                apply_settings(opts.settings, so);
                const torch::Tensor r =
                    px.active() ? stack_radius_on_proxy(*d, small, prep.motion, px, so, &report)
                                : estimate_radius_from_stack(*d, so, &report);
                const double scale = px.active() ? std::sqrt(px.sx * px.sy) : 1.0;
                d->fixed_focus_share = report.fixed_focus_share;
                log.info("radius: " + report.summary);
                try {
                    save_stack_radius(project, r, key, d->fixed_focus_share, scale);
                } catch (const std::exception& e) {
                    log.info(std::string("radius: not cached (") + e.what() + ")");
                }
                if (!px.active() && (d->mapped_dir.empty() || is_mapped(r))) {
                    d->radius = r;
                } else {
                    d->radius = d->clip_array({T, H, W}, "radius");
                    std::vector<char> ok(T, 0);  // checked while the frame is at hand
                    at::parallel_for(0, T, 1, [&](int64_t t0, int64_t t1) {
                        for (int64_t t = t0; t < t1; ++t) {
                            d->radius[t].copy_(radius_at_size(r[t], H, W, scale));
                            ok[t] = finite_radius(d->radius[t]);
                        }
                    });
                    d->radius_finite = std::all_of(ok.begin(), ok.end(), [](char v) { return v; });
                }
            }
            log.info(std::string("radius: ") + (cached.defined() ? "reused from prep/, " : "") +
                     "estimated per frame from the clip as a focal stack (median " +
                     std::to_string(sampled_median(d->radius)).substr(0, 4) + " px)");
        } else {
            log.info("radius: estimated per frame (edge reblur ratio, guided filter)");
        }
    }
    std::vector<Image>().swap(small);  // the proxies served the preparation and the radius
    release_freed_memory();
    debug_memory("setup: radius estimated");
    if (!d->cache_dir.empty()) {
        clock.next("data: keeping the arrays", "keeping the clip's arrays");
        d->cache_key = clip_cache_key(project, opts);  // the preparation may be new
        keep_clip(*d, log);
    }
    return finish_fit_data(d, opts, log);
}

}  // namespace refocus
