#include "session/fit_session.h"

#include <torch/torch.h>

#include <cmath>
#include <future>
#include <thread>

#include "edit/atlas_edit.h"
#include "edit/depth.h"
#include "edit/focus.h"
#include "edit/recompose.h"
#include "edit/uv_flow.h"
#include "io/tensor_image.h"
#include "io/clip.h"
#include "io/image_file.h"
#include "util/error.h"
#include "util/json_file.h"
#include "util/timing.h"

namespace refocus {

using nlohmann::json;

fs::path fit_dir(const Project& project) {
    return project.dir / "fit";
}

void use_settings(FitSettings& s, const Settings& settings) {
    s.fit.settings = settings;
    s.setup.settings = settings;
    apply_settings(settings, s.fit);
    apply_settings(settings, s.setup);
}

FitSettings read_fit_settings(const Project& p) {
    FitSettings s;
    if (!p.sections.contains("fit")) return s;
    const json& f = p.sections.at("fit");
    const std::string label = p.project_file().string();
    try {
        s.fit.preset = f.value("preset", s.fit.preset);
        s.fit.seed = f.value("seed", s.fit.seed);
        s.fit.minutes = f.value("minutes", 0.0);
        s.fit.iters = f.value("iters", int64_t(0));
        s.fit.batch = f.value("batch", s.fit.batch);
        s.setup.coc_path = f.value("coc", std::string());
        s.setup.mask_path = f.value("mask", std::string());
        // A project that names no kernel was fitted with the paper's disk, and keeps it (its
        // checkpoints' atlases and radii are in its terms).
        s.setup.kernel = f.value("kernel", std::string("disk"));
        if (f.contains("settings"))
            s.fit.settings.set_json(f["settings"], label + ": fit.settings");
    } catch (const json::exception& e) {
        throw Error(file_error(label, std::string("malformed 'fit' section: ") + e.what()));
    }
    use_settings(s, s.fit.settings);
    try {
        fit_kernel_params(s.setup.kernel);
    } catch (const Error& e) {
        throw Error(file_error(label, std::string("malformed 'fit' section: ") + e.what()));
    }
    // Relative inputs are stored relative to the project folder.
    for (std::string* path : {&s.setup.coc_path, &s.setup.mask_path})
        if (!path->empty() && fs::path(*path).is_relative()) *path = (p.dir / *path).string();
    return s;
}

void write_fit_settings(Project& p, const FitSettings& s, const FitSnapshot* snap) {
    auto rel = [&](const std::string& path) -> std::string {
        if (path.empty()) return path;
        fs::path r = fs::absolute(path).lexically_relative(fs::absolute(p.dir));
        return r.empty() ? path : r.string();
    };
    json f = {{"preset", s.fit.preset},
              {"seed", s.fit.seed},
              {"minutes", s.fit.minutes},
              {"iters", s.fit.iters},
              {"batch", s.fit.batch},
              {"coc", rel(s.setup.coc_path)},
              {"mask", rel(s.setup.mask_path)},
              {"kernel", s.setup.kernel},
              {"checkpoint", "fit/checkpoint.json"}};
    if (!s.fit.settings.empty()) f["settings"] = s.fit.settings.to_json();
    if (snap)
        f["status"] = {{"state", snap->status},
                       {"step", snap->step},
                       {"elapsed_s", snap->elapsed_s},
                       {"reblur_psnr", snap->reblur_psnr}};
    // What is stored must load again: the loader's own check, before anything is written.
    check_fit_section(f, p.project_file().string() + " (not written)");
    p.sections["fit"] = f;
    p.save_merged({"fit"});
}

namespace {
// Whether the checkpoint in `dir` holds its atlases' geometry (the fast model's placement and
// alignment): then the model's set-up need not align the frames again, the checkpoint's
// geometry replaces whatever it would find. Checkpoints from before per-tensor checksums are
// not known to: they get the full set-up.
bool checkpoint_holds_geometry(const fs::path& dir) {
    try {
        const nlohmann::json j = read_json_file((dir / "checkpoint.json").string());
        const auto sums = j.find("checksums");
        if (sums == j.end() || !sums->is_object() || !sums->contains("model/bg_to_atlas"))
            return false;
        bool fg = false;
        for (const auto& [name, v] : sums->items()) fg = fg || name.rfind("model/fg_", 0) == 0;
        return !fg || sums->contains("model/fg_to_atlas");
    } catch (const std::exception&) {
        return false;  // load_checkpoint says what is wrong
    }
}
}  // namespace

FitOptions restoring_options(const Project& p, FitOptions fit) {
    // ECC alignment is most of the set-up, and the checkpoint's geometry replaces what it finds;
    // fusing the atlases is the rest of it, and the checkpoint replaces them too.
    if (fit.preset == "fast" && FitEngine::has_checkpoint(fit_dir(p)) &&
        checkpoint_holds_geometry(fit_dir(p))) {
        fit.settings.set("fast.align_rounds", "0");
        fit.settings.set("fast.restore_only", "1");
    }
    return fit;
}

std::unique_ptr<FitEngine> open_fitted(const Project& p, PrepareLog& log) {
    if (!FitEngine::has_checkpoint(fit_dir(p)))
        throw Error(file_error(p.project_file().string(),
                               "the project has not been fitted yet (run: refocus fit " +
                                   p.dir.string() + " --minutes 5)"));
    FitSettings s = read_fit_settings(p);
    // A checkpoint from before the cleaned masks' track ("flow-v2") rebuilds its model on the
    // masks as stored, which the kept arrays (model/clip_cache.h) do not hold.
    try {
        const auto j = read_json_file((fit_dir(p) / "checkpoint.json").string());
        if (j.value("subject_track", std::string()) != "flow-v2") s.setup.clip_cache = false;
    } catch (const std::exception&) {
        // load_checkpoint says what is wrong
    }
    StageClock clock;  // --debug timing
    clock.next("open: the clip's data");
    auto data = build_fit_data(p, s.setup, log);
    if (s.fit.minutes <= 0 && s.fit.iters <= 0) s.fit.iters = 1;
    clock.next("open: the model");
    auto engine = std::make_unique<FitEngine>(data, restoring_options(p, s.fit));
    clock.next("open: the checkpoint");
    engine->load_checkpoint(fit_dir(p), FitEngine::CheckpointUse::Read);
    return engine;
}

namespace {
// `path` with symbolic links and "..' resolved as far as it exists.
fs::path resolved(const fs::path& path) {
    std::error_code ec;
    fs::path r = fs::weakly_canonical(fs::absolute(path), ec);
    return ec ? fs::absolute(path).lexically_normal() : r;
}

bool same_or_inside(const fs::path& path, const fs::path& dir) {
    auto p = path.begin();
    for (auto d = dir.begin(); d != dir.end(); ++d, ++p) {
        if (d->empty()) continue;  // a trailing "/"
        if (p == path.end() || *p != *d) return false;
    }
    return true;
}
}  // namespace

void check_export_target(const Project& p, const fs::path& target) {
    const fs::path t = resolved(target);
    const fs::path dir = resolved(p.dir);
    for (const char* own : {Project::kFileName, "fit", "frames", "prep", "edits", "depth"})
        if (same_or_inside(t, dir / own))
            throw Error(
                file_error(target.string(),
                           (std::string(own) == Project::kFileName
                                ? std::string("is the project's own ") + own
                                : std::string("is inside the project's own ") + own + "/ folder") +
                               ": an export never writes over a project; choose another --out"));
    std::vector<std::pair<fs::path, std::string>> inputs;
    fs::path source = p.source;
    if (source.is_relative()) source = p.dir / source;
    if (p.source_kind == "sequence")
        inputs.push_back({fs::is_directory(source) ? source : source.parent_path(),
                          "the folder of the source frames"});
    else
        inputs.push_back({source, "the source clip"});
    FitSettings s;
    try {
        s = read_fit_settings(p);
    } catch (const Error&) {  // the fit section is reported by whoever reads it
    }
    if (!s.setup.coc_path.empty())
        inputs.push_back(
            {fs::path(s.setup.coc_path).parent_path(), "the folder of the --coc maps"});
    if (!s.setup.mask_path.empty())
        inputs.push_back(
            {fs::path(s.setup.mask_path).parent_path(), "the folder of the --mask mattes"});
    for (const auto& [path, what] : inputs)
        if (!path.empty() && same_or_inside(t, resolved(path)))
            throw Error(file_error(target.string(), "is " + what + " (" + path.string() +
                                                        "): an export never writes over its "
                                                        "inputs; choose another --out"));
}

ExportPass parse_export_pass(const std::string& n) {
    if (n == "sharp") return ExportPass::Sharp;
    if (n == "reblur") return ExportPass::Reblur;
    if (n == "atlas") return ExportPass::Atlas;
    if (n == "alpha") return ExportPass::Alpha;
    if (n == "coc") return ExportPass::Coc;
    if (n == "uv") return ExportPass::Uv;
    if (n == "refocus") return ExportPass::Refocus;
    if (n == "depth") return ExportPass::Depth;
    if (n == "confidence") return ExportPass::Confidence;
    if (n == "flow") return ExportPass::Flow;
    if (n == "parallax") return ExportPass::Parallax;
    throw Error("unknown pass '" + n +
                "' (use sharp, reblur, atlas, alpha, coc, uv, refocus, depth, confidence, flow, "
                "parallax or all)");
}

bool is_data_pass(ExportPass p) {
    return p == ExportPass::Coc || p == ExportPass::Uv || p == ExportPass::Depth ||
           p == ExportPass::Flow;
}

const char* export_pass_name(ExportPass p) {
    switch (p) {
        case ExportPass::Sharp:
            return "sharp";
        case ExportPass::Reblur:
            return "reblur";
        case ExportPass::Atlas:
            return "atlas";
        case ExportPass::Alpha:
            return "alpha";
        case ExportPass::Coc:
            return "coc";
        case ExportPass::Uv:
            return "uv";
        case ExportPass::Refocus:
            return "refocus";
        case ExportPass::Depth:
            return "depth";
        case ExportPass::Flow:
            return "flow";
        case ExportPass::Confidence:
            return "confidence";
        case ExportPass::Parallax:
            return "parallax";
    }
    return "?";
}

std::string FallbackShare::summary() const {
    if (frames == 0) return "no frame made from the sharp plate";
    char buf[256];
    int n = std::snprintf(buf, sizeof buf,
                          "the plate is the shot on %.1f%% of pixels the fit cannot explain",
                          100 * unexplained / frames);
    if (worst_frame >= 0 && worst_share > 0.001)
        n += std::snprintf(buf + n, sizeof buf - n, " (most in frame %d: %.1f%%)", worst_frame,
                           100 * worst_share);
    std::snprintf(buf + n, sizeof buf - n,
                  ", on %.1f%% that no frame saw sharp, on %.1f%% that no other frame saw sharper,"
                  " and on %.1f%% where nothing is blurred",
                  100 * unseen / frames, 100 * not_sharper / frames, 100 * in_focus / frames);
    std::string out = buf;
    // Whether the fit is trusted (docs/method.md, A fit that explains the clip): the residual
    // against the noise decides it.
    if (std::isfinite(residual_rms) && !std::isfinite(trust)) {
        std::snprintf(buf, sizeof buf,
                      "; the reblur meets the input to %.2f levels RMS (noise %.2f)", residual_rms,
                      noise);
        out += buf;
    } else if (std::isfinite(residual_rms)) {
        std::snprintf(buf, sizeof buf,
                      "; the reblur meets the input to %.2f levels RMS (noise %.2f): %s",
                      residual_rms, noise,
                      trust >= 0.999   ? (deconvolves ? "the fit explains the clip, its "
                                                        "deconvolution is kept"
                                                      : "the fit explains the clip, the lock "
                                                        "reads its reblur")
                      : trust <= 0.001 ? "the fit does not explain the clip, the lock holds it "
                                         "to the input's low band"
                                       : "the fit is partly trusted");
        out += buf;
        if (trust > 0.001 && trust < 0.999) {
            std::snprintf(buf, sizeof buf, " (%.2f)", trust);
            out += buf;
        }
    }
    return out;
}

namespace {
// Adds frame t to `s` (see FallbackShare).
void count_fallback(const FitEngine& engine, int t, FallbackShare& s) {
    auto f = engine.fallback_weight(t);
    torch::Tensor g;  // γ_t, from model_weight's own dilation
    auto w = engine.model_weight(t, &g);
    auto tau = engine.seen_trust_map(t);
    const double u = f.defined() ? f.mean().item<double>() : 0.0;
    // Explained but seen sharp by no frame: (1 − f)·(1 − τ).
    const double unseen =
        tau.defined()
            ? ((f.defined() ? 1.0 - f : torch::ones_like(tau)) * (1.0 - tau)).mean().item<double>()
            : 0.0;
    // Explained and seen sharp, but no other frame saw it sharper: (1 − f)·τ·(1 − γ).
    double not_sharper = 0;
    if (g.defined()) {
        auto kept = f.defined() ? 1.0 - f : torch::ones_like(g);
        if (tau.defined()) kept = kept * tau;
        not_sharper = (kept * (1.0 - g)).mean().item<double>();
    }
    // The rest of the shot's share: in focus (w = (1 − f)·τ·γ·need).
    const double shot = w.defined() ? (1.0 - w).mean().item<double>() : 0.0;
    s.unexplained += u;
    s.unseen += unseen;
    s.not_sharper += not_sharper;
    s.in_focus += std::max(0.0, shot - u - unseen - not_sharper);
    if (u > s.worst_share) s.worst_share = u, s.worst_frame = t;
    if (s.frames == 0) {
        s.residual_rms = engine.residual_rms();
        s.noise = engine.data().noise_levels;
        s.trust = engine.reported_trust();  // NaN: off, and the line gives the residual only
        s.deconvolves = engine.options().trusted_blur_px > 0;
    }
    ++s.frames;
}

// The project's atlas edits as deltas over the current atlases (undefined: no edit).
std::pair<torch::Tensor, torch::Tensor> edit_deltas(FitEngine& engine, const ProjectEdits* e) {
    if (!e || !e->has_edits()) return {};
    std::lock_guard<std::mutex> lock(engine.model_mutex());
    if (!engine.has_atlas())
        throw Error("the project has atlas edits but the perframe preset has no atlas");
    torch::NoGradGuard g;
    torch::Tensor fg = engine.model().atlas_fg();
    if (e->fg.has_edits() && !fg.defined())
        throw Error(file_error(e->fg.label(), "foreground edit, but the fit has one layer"));
    return {e->bg.delta(engine.model().atlas_bg()),
            fg.defined() ? e->fg.delta(fg) : torch::Tensor()};
}
}  // namespace

// No export writes a NaN/Inf pixel: a fit that produced one is refused before anything is
// renamed into place (the writer's staging is removed as the error unwinds).
void refuse_nonfinite(const Image& img, const std::string& what, int t) {
    long first = -1;
    const size_t bad = count_nonfinite(img, &first);
    if (bad == 0) return;
    throw Error(what + (t >= 0 ? " frame " + std::to_string(t) : std::string()) + ": " +
                std::to_string(bad) +
                " NaN/Inf value(s) in the fit's result; nothing was written (the fit is damaged: "
                "fit again without --resume)");
}

struct PassFrames::State {
    torch::Tensor bg, fg;  // the edits' deltas
    FocusTrack track;
    DepthModel depth;
    int threads = 1;
};

PassFrames::~PassFrames() = default;

PassFrames::PassFrames(FitEngine& engine, ExportPass pass, bool three_channels,
                       const ExportOptions& o)
    : m_engine(engine), m_pass(pass), m_three(three_channels), m_opts(o), m(new State) {
    const std::string name = export_pass_name(pass);
    m_needs_project = pass == ExportPass::Refocus || pass == ExportPass::Depth;
    if (m_needs_project && !o.project)
        throw Error("--what " + name + " needs the project (its depth and focus keys)");
    std::tie(m->bg, m->fg) = edit_deltas(engine, pass == ExportPass::Depth ? nullptr : o.edits);
    // Refocus / depth: validate the focus keys and fit (or load) the depth before the work.
    if (m_needs_project) {
        m->track = o.focus ? *o.focus : read_focus(*o.project);
        m->depth = project_depth(engine, o.project->dir);
    }
    m->threads = std::max(1, int(std::thread::hardware_concurrency()));
}

Image PassFrames::frame(int t) {
    const FitData& d = m_engine.data();
    torch::NoGradGuard no_grad;
    StageClock clock;  // --debug timing
    clock.next("export: render the layers");
    Layers L = m_engine.render_frame(t);
    const Layers model = L;
    apply_edits(L, m->bg, m->fg);
    // The sharp plate and what is made from it fall back to the shot where the fit failed
    // (the edits stay on top); the reblur and the layers stay the model's.
    if (m_pass == ExportPass::Sharp || m_needs_project) {
        clock.next("export: output rules (fallback)");
        m_engine.apply_fallback(L, t, &model);
        if (m_opts.fallback) count_fallback(m_engine, t, *m_opts.fallback);
    }
    clock.next(std::string("export: the ") + export_pass_name(m_pass) + " pass");
    if (m_needs_project) {
        const FrameMaps fm = frame_maps(L);
        return m_pass == ExportPass::Depth
                   ? m->depth.depth_map(t, fm.uv_bg, fm.uv_fg, fm.alpha)
                   : render_refocused(fm, m->depth, t, m->track.lens_at(t, &m->depth), m->threads);
    }
    torch::Tensor img;
    switch (m_pass) {
        case ExportPass::Sharp:
            img = L.sharp[0];
            break;
        case ExportPass::Reblur:
            img = m_engine.reblur(L, {t})[0];
            break;
        case ExportPass::Alpha:
            img = L.alpha.defined() ? L.alpha[0] : torch::zeros({1, d.height, d.width});
            if (m_three) img = img.expand({3, d.height, d.width});
            break;
        case ExportPass::Coc:
            img = d.radius[t].unsqueeze(0);
            break;
        case ExportPass::Confidence:
            img = m_engine.confidence(t)[0];
            if (m_three) img = img.expand({3, d.height, d.width});
            break;
        case ExportPass::Uv: {
            // (u, v[, u_fg, v_fg]) in [-1, 1]; 2 channels are padded to 3 (RGB layouts).
            img = L.uv_bg[0].permute({2, 0, 1});
            if (L.uv_fg.defined()) img = torch::cat({img, L.uv_fg[0].permute({2, 0, 1})}, 0);
            if (img.size(0) == 2)
                img = torch::cat({img, torch::zeros_like(img[0]).unsqueeze(0)}, 0);
            break;
        }
        case ExportPass::Flow:  // forward flow t -> t+1 from the mappings; 0 at the last frame
            return t + 1 < d.frames ? uv_flow(L, m_engine.render_frame(t + 1))
                                    : Image(d.width, d.height, 3, 0.0f);
        default:
            throw Error(std::string("--what ") + export_pass_name(m_pass) + " has no frames");
    }
    return tensor_to_image(img.contiguous());
}

ClipWriteOptions pass_write_options(ExportPass pass, double fps) {
    ClipWriteOptions wo;
    wo.fps = fps;
    wo.srgb_encode = !(pass == ExportPass::Alpha || pass == ExportPass::Confidence);
    return wo;
}

ClipFormat pass_clip_format(ExportPass pass, const std::string& format) {
    const bool data_pass = is_data_pass(pass);
    if (data_pass && format != "exr" && format != "exr32")
        throw Error(std::string("--what ") + export_pass_name(pass) +
                    " holds values in px / atlas coordinates / inverse depth / px of flow: use "
                    "--format exr");
    return parse_clip_format(format == "exr" && data_pass ? "exr32" : format);
}

std::vector<std::string> export_pass(FitEngine& engine, ExportPass pass, const std::string& format,
                                     const std::string& out, const ExportOptions& o) {
    const std::string name = export_pass_name(pass);
    if (o.project) check_export_target(*o.project, out);
    if (pass == ExportPass::Atlas) {
        if (format == "mp4") throw Error("an atlas is an image: use --format png, tiff or exr");
        const auto [d_bg, d_fg] = edit_deltas(engine, o.edits);
        std::error_code ec;
        fs::create_directories(out, ec);
        const PixelFormat pf = parse_pixel_format(format);
        std::vector<std::string> files;
        auto write = [&](torch::Tensor t, const torch::Tensor& delta, const std::string& layer) {
            if (!t.defined()) return;
            if (delta.defined()) t = t + delta[0];
            std::string path =
                (fs::path(out) / ("atlas_" + layer + "." + extension_of(pf))).string();
            const Image img = tensor_to_image(t.clamp_min(0));
            refuse_nonfinite(img, "atlas_" + layer, -1);
            write_image_file(path, img, pf);
            files.push_back(path);
        };
        std::lock_guard<std::mutex> lock(engine.model_mutex());
        if (!engine.has_atlas())
            throw Error("the perframe preset has no atlas (it deconvolves each frame alone)");
        write(engine.model().atlas_bg(), d_bg, "bg");
        write(engine.model().atlas_fg(), d_fg, "fg");
        return files;
    }
    if (pass == ExportPass::Parallax) {
        // γ over the background atlas (fast_model.h, plane + parallax): one image for the clip.
        if (format != "exr" && format != "exr32")
            throw Error(
                "--what parallax holds the background's parallax (px at the frame of "
                "largest camera motion, in atlas space): use --format exr");
        std::lock_guard<std::mutex> lock(engine.model_mutex());
        const torch::Tensor g = engine.has_atlas() ? engine.model().parallax_bg() : torch::Tensor();
        if (!g.defined())
            throw Error(
                "the fit has no parallax field: a static camera, a preset other than fast, "
                "or fast.parallax off when it was fitted");
        std::error_code ec;
        fs::create_directories(out, ec);
        const std::string path = (fs::path(out) / "parallax_bg.exr").string();
        const Image img = tensor_to_image(g);
        refuse_nonfinite(img, "parallax_bg", -1);
        write_image_file(path, img, PixelFormat::ExrFloat);
        return {path};
    }
    const ClipFormat cf = pass_clip_format(pass, format);
    const FitData& d = engine.data();
    const int first = o.first, last = o.last < 0 ? d.frames - 1 : o.last;
    if (first < 0 || first > last || last >= d.frames)
        throw Error("frame range " + std::to_string(first) + ".." + std::to_string(last) +
                    " is not inside the clip's frames 0.." + std::to_string(d.frames - 1));
    PassFrames frames(engine, pass, cf == ClipFormat::Mp4, o);
    ClipWriter writer(out, name, cf, pass_write_options(pass, o.fps));
    // Frame t is written (encoded, compressed) on a second thread while frame t + 1 is made; one
    // write at a time keeps the order. An error in either is raised here.
    std::future<void> pending;
    auto finish_write = [&] {
        if (pending.valid()) pending.get();
    };
    try {
        for (int t = first; t <= last; ++t) {
            Image frame = frames.frame(t);
            refuse_nonfinite(frame, name, t);
            finish_write();
            pending = std::async(std::launch::async, [&writer, f = std::move(frame)] {
                ScopedTiming timing("export: write");
                writer.write(f);
            });
            if (o.progress && !o.progress(t - first + 1, last - first + 1)) {
                finish_write();
                writer.cancel();
                throw Error("export cancelled");
            }
        }
        finish_write();
    } catch (...) {
        if (pending.valid()) pending.wait();  // the writer outlives its last write
        throw;
    }
    return writer.finish();
}

}  // namespace refocus
