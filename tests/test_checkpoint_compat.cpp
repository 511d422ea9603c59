// Checkpoints and projects written by earlier builds load as the build that wrote them; a
// reopened project rebuilds the model its fit trained.
#include <nlohmann/json.hpp>
#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <cstdlib>
#include <fstream>

#include "fit/fit_engine.h"
#include "session/fit_session.h"
#include "fit/fit_setup.h"
#include "io/image_file.h"
#include "io/tensor_image.h"
#include "metrics/metrics.h"
#include "model/atlas_geometry.h"
#include "project/project.h"
#include "util/error.h"
#include "util/mapped.h"
#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

// A fast fit of tiny_two_layer_data(seed) with a budget of `iters`, stepped `steps` times and
// checkpointed in the scratch directory `name`.
struct SteppedFit {
    std::shared_ptr<FitData> data;
    FitOptions opts;
    std::unique_ptr<FitEngine> engine;
    fs::path ck;
};
SteppedFit stepped_fit(unsigned seed, int64_t iters, int steps, const std::string& name) {
    SteppedFit f;
    f.data = tiny_two_layer_data(seed);
    f.opts.preset = "fast";
    f.opts.iters = iters;
    f.engine = std::make_unique<FitEngine>(f.data, f.opts);
    for (int i = 0; i < steps; ++i) f.engine->step();
    f.ck = scratch_dir(name);
    f.engine->save_checkpoint(f.ck);
    return f;
}

TEST_CASE(
    "a checkpoint without the shared matte or the track's kind loads as the build that wrote it") {
    SteppedFit f = stepped_fit(5, 4, 2, "fit_old_checkpoint");
    auto& [data, o, engine, ck] = f;
    FitEngine& a = *engine;
    // As an earlier build wrote it: no "subject_track" field.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    strip_checksums(j);  // as an earlier build wrote it
    CHECK(j.at("subject_track") == "flow-v2");
    j.erase("subject_track");
    write_file_atomic(ck / "checkpoint.json", j.dump());
    auto data_b = std::make_shared<FitData>(*data);
    FitEngine b(data_b, o);
    b.load_checkpoint(ck);
    CHECK(b.data().legacy_subject_track);
    // (Without flow both tracks are the masks' centroids, so the tensors fit either way.)
    CHECK(torch::equal(a.render_frame(1).sharp, b.render_frame(1).sharp));
    // An earlier build's state lacks the shared matte: its per-frame matte is all of alpha.
    auto state = a.model().state();
    auto logits = state.at("alpha_logit").clone();
    state.erase("alpha_atlas");
    b.model().load_state(state);
    auto alpha = b.render_frame(2).alpha;
    auto want = torch::sigmoid(torch::nn::functional::interpolate(
        logits.narrow(0, 2, 1), torch::nn::functional::InterpolateFuncOptions()
                                    .size(std::vector<int64_t>{24, 40})
                                    .mode(torch::kBilinear)
                                    .align_corners(false)));
    CHECK(torch::allclose(alpha, want, 1e-5, 1e-5));
}

TEST_CASE(
    "the fit's kernel: new fits take the pillbox, projects and checkpoints of earlier builds keep "
    "the disk") {
    // A checkpoint names its kernel; a version 1 checkpoint without the field was fitted with
    // the paper's disk (its migration writes that out).
    SteppedFit f = stepped_fit(6, 4, 2, "fit_kernel_checkpoint");
    auto j = nlohmann::json::parse(read_text_file(f.ck / "checkpoint.json"));
    strip_checksums(j);               // as an earlier build wrote it
    CHECK(j.at("kernel") == "disk");  // tiny_two_layer_data keeps FitData's default
    j.erase("kernel");
    j["version"] = 1;
    write_file_atomic(f.ck / "checkpoint.json", j.dump());
    {
        FitEngine same(std::make_shared<FitData>(*f.data), f.opts);
        CHECK_NOTHROW(same.load_checkpoint(f.ck));
        CHECK(torch::equal(same.render_frame(1).sharp, f.engine->render_frame(1).sharp));
    }
    auto pillbox = std::make_shared<FitData>(*f.data);
    pillbox->blur = fit_kernel_params("pillbox");
    FitEngine other(pillbox, f.opts);
    try {
        other.load_checkpoint(f.ck);
        FAIL("a disk checkpoint loaded into a pillbox fit");
    } catch (const Error& e) {
        const std::string m = e.what();
        CHECK(m.find("checkpoint.json") != std::string::npos);
        CHECK(m.find("'kernel' is \"disk\"") != std::string::npos);
        CHECK(m.find("pillbox") != std::string::npos);
    }
    CHECK_THROWS_WITH_AS(fit_kernel_params("gauss"), doctest::Contains("unknown kernel 'gauss'"),
                         Error);
    CHECK(fit_kernel_params("pillbox").kernel == BlurKernel::Pillbox);
    CHECK(fit_kernel_params("disk").kernel == BlurKernel::Disk);

    // Settings: fresh ones take the pillbox; a project's "fit" section without a kernel (an
    // earlier build's) reads as the disk; what is written is read back.
    CHECK(FitSettings{}.setup.kernel == "pillbox");
    TinyClip c = make_tiny("fit_kernel_settings");
    Project p = Project::load(c.project);
    FitSettings s;
    s.fit.iters = 3;
    s.setup.kernel = "pillbox";
    write_fit_settings(p, s, nullptr);
    CHECK(read_fit_settings(Project::load(c.project)).setup.kernel == "pillbox");
    auto pj = nlohmann::json::parse(read_text_file(p.project_file()));
    pj.at("fit").erase("kernel");
    write_file_atomic(p.project_file(), pj.dump());
    CHECK(read_fit_settings(Project::load(c.project)).setup.kernel == "disk");
    pj.at("fit")["kernel"] = "bokeh";
    write_file_atomic(p.project_file(), pj.dump());
    CHECK_THROWS_WITH_AS(
        read_fit_settings(Project::load(c.project)),
        doctest::Contains("project.json: malformed 'fit' section: fit: unknown kernel 'bokeh'"),
        Error);
    PrepareLog log;
    FitSetupOptions so;
    so.kernel = "disk";
    CHECK(build_fit_data(Project::load(c.project), so, log)->blur.kernel == BlurKernel::Disk);
    so.kernel = "pillbox";
    CHECK(build_fit_data(Project::load(c.project), so, log)->blur.kernel == BlurKernel::Pillbox);
}

namespace {
// Flips bytes in the middle of `file`.
void damage(const fs::path& file) {
    std::string bytes = read_text_file(file);
    for (size_t i = bytes.size() / 3; i < bytes.size() / 3 + 64; ++i) bytes[i] ^= 0x5a;
    std::ofstream(file, std::ios::binary) << bytes;
}

fs::path checkpoint_file(const fs::path& ck, const char* key) {
    const auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    return ck / j.at(key).get<std::string>();
}
}  // namespace

TEST_CASE(
    "a checkpoint opened for reading maps its residual and reads the optimizer when a step needs "
    "it: the same fit") {
    SteppedFit f = stepped_fit(7, 12, 3, "fit_read_open");
    CHECK(fs::exists(checkpoint_file(f.ck, "optimizer")));
    CHECK(fs::file_size(checkpoint_file(f.ck, "residual")) ==
          uintmax_t(f.data->frames * f.data->height * f.data->width) * sizeof(float));
    FitEngine train(std::make_shared<FitData>(*f.data), f.opts);
    train.load_checkpoint(f.ck);
    FitEngine read(std::make_shared<FitData>(*f.data), f.opts);
    read.load_checkpoint(f.ck, FitEngine::CheckpointUse::Read);
    // The output rules read the same residual.
    CHECK(read.residual_rms() == train.residual_rms());
    CHECK(std::isfinite(read.residual_rms()));
    for (int t : {0, 3}) {
        const auto a = train.fallback_weight(t), b = read.fallback_weight(t);
        CHECK(a.defined() == b.defined());
        if (a.defined() && b.defined()) CHECK(torch::equal(a, b));
    }
    // Stepped on, the one opened for reading reads what it left on disk: the same fit.
    for (int i = 0; i < 3; ++i) train.step(), read.step();
    const auto sa = train.model().state(), sb = read.model().state();
    REQUIRE(sa.size() == sb.size());
    for (const auto& [name, t] : sa) {
        INFO(name);
        CHECK(torch::equal(t, sb.at(name)));
    }

    // A damaged residual is named when its frames are read; a damaged optimizer state when a
    // step needs it (an export, which does not, still opens).
    const fs::path saved = scratch_dir("fit_read_open_damaged");
    fs::copy(f.ck, saved, fs::copy_options::recursive | fs::copy_options::overwrite_existing);
    damage(checkpoint_file(saved, "residual"));
    FitEngine r1(std::make_shared<FitData>(*f.data), f.opts);
    CHECK_THROWS_WITH_AS(r1.load_checkpoint(saved, FitEngine::CheckpointUse::Read),
                         doctest::Contains(".resid: damaged checkpoint residual: frame"), Error);
    fs::copy(f.ck, saved, fs::copy_options::recursive | fs::copy_options::overwrite_existing);
    damage(checkpoint_file(saved, "optimizer"));
    FitEngine r2(std::make_shared<FitData>(*f.data), f.opts);
    CHECK_NOTHROW(r2.load_checkpoint(saved, FitEngine::CheckpointUse::Read));
    CHECK(r2.render_frame(1).sharp.defined());
    CHECK_THROWS_WITH_AS(r2.step(), doctest::Contains(".optim.pt: damaged checkpoint tensors"),
                         Error);
    FitEngine r3(std::make_shared<FitData>(*f.data), f.opts);
    CHECK_THROWS_WITH_AS(r3.load_checkpoint(saved),
                         doctest::Contains(".optim.pt: damaged checkpoint tensors"), Error);
    CHECK(FitEngine::checkpoint_problem(saved, f.data->frames).find(".optim.pt: damaged") !=
          std::string::npos);
    // A missing residual is named before anything is restored.
    fs::remove(checkpoint_file(saved, "residual"));
    FitEngine r4(std::make_shared<FitData>(*f.data), f.opts);
    CHECK_THROWS_WITH_AS(r4.load_checkpoint(saved, FitEngine::CheckpointUse::Read),
                         doctest::Contains(".resid: the checkpoint's tensor file is missing"),
                         Error);
}

TEST_CASE(
    "renders and output rules kept for the frames around the one asked for equal fresh ones") {
    // An export asks for frame t's layers, then the rules (which render t - k ... t + k), then
    // the rules again for its report: the engine keeps them. Asked in export order or backwards
    // (where nothing kept is used), from the same checkpoint, they must be the same.
    SteppedFit f = stepped_fit(8, 12, 4, "fit_render_memo");
    FitEngine a(std::make_shared<FitData>(*f.data), f.opts),
        b(std::make_shared<FitData>(*f.data), f.opts);
    a.load_checkpoint(f.ck, FitEngine::CheckpointUse::Read);
    b.load_checkpoint(f.ck, FitEngine::CheckpointUse::Read);
    const int T = int(f.data->frames);
    std::vector<Layers> la(T), lb(T);
    std::vector<torch::Tensor> wa(T), wb(T), fa(T), fb(T);
    for (int t = 0; t < T; ++t) {
        la[t] = a.render_frame(t);
        wa[t] = a.model_weight(t);
        fa[t] = a.fallback_weight(t);
        CHECK(a.model_weight(t).defined() == wa[t].defined());
    }
    for (int t = T - 1; t >= 0; --t) {
        fb[t] = b.fallback_weight(t);
        wb[t] = b.model_weight(t);
        lb[t] = b.render_frame(t);
    }
    bool some_fallback = false;
    for (int t = 0; t < T; ++t) {
        INFO("frame " << t);
        CHECK(torch::equal(la[t].sharp, lb[t].sharp));
        CHECK(torch::equal(la[t].bg, lb[t].bg));
        REQUIRE(wa[t].defined() == wb[t].defined());
        if (wa[t].defined()) CHECK(torch::equal(wa[t], wb[t]));
        REQUIRE(fa[t].defined() == fb[t].defined());
        if (fa[t].defined()) CHECK(torch::equal(fa[t], fb[t]));
        some_fallback = some_fallback || fa[t].defined();
    }
    CHECK(some_fallback);  // the rules had work to do
    // A step changes the model: nothing kept from before it is used.
    const Layers before = a.render_frame(1);
    a.step();
    const Layers after = a.render_frame(1);
    CHECK_FALSE(torch::equal(before.sharp, after.sharp));
}

TEST_CASE("a reopened project rebuilds the model its fit trained: the masks are used as stored") {
    // The subject's track and atlas box come from the masks; the fit that prepared them and a
    // later export (which reads them back from 8-bit PNG) must agree to the pixel.
    TinyClip c = make_tiny("fit_reopen_masks", "hunt", "160x90");
    Project p = Project::load(c.project);
    PrepareLog log;
    auto fresh = build_fit_data(p, {}, log);
    auto reused = build_fit_data(p, {}, log);
    REQUIRE(fresh->has_subject == reused->has_subject);
    MESSAGE("tiny hunt clip: " << std::string(fresh->has_subject ? "two layers" : "one layer"));
    if (fresh->has_subject) CHECK(torch::equal(fresh->mask, reused->mask));
    auto a = make_model("fast", *fresh, 1), b = make_model("fast", *reused, 1);
    CHECK(a->atlas_bg().sizes() == b->atlas_bg().sizes());
    if (fresh->has_subject) {
        CHECK(a->atlas_fg().sizes() == b->atlas_fg().sizes());
        CHECK(torch::equal(a->state().at("alpha_atlas"), b->state().at("alpha_atlas")));
    }
}

TEST_CASE(
    "a checkpoint keeps its atlases' geometry: a build that would place them otherwise renders "
    "what was trained") {
    SteppedFit f = stepped_fit(7, 6, 3, "fit_geometry_checkpoint");
    auto& [data, o, engine, ck] = f;
    FitEngine& a = *engine;
    // The same clip whose masks now say the subject is wider and lower: this build computes
    // another foreground box and track for it.
    auto data_b = std::make_shared<FitData>(*data);
    data_b->mask = torch::zeros_like(data->mask);
    data_b->mask.narrow(2, 11, 10).narrow(3, 9, 16).fill_(1.0f);
    FitEngine b(data_b, o);
    REQUIRE_FALSE(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    b.load_checkpoint(ck);
    CHECK(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    CHECK(torch::equal(a.render_frame(2).sharp, b.render_frame(2).sharp));
    CHECK(torch::equal(a.render_frame(2).alpha, b.render_frame(2).alpha));
    // Training goes on from there (the optimiser follows the adopted tensors; its masks differ,
    // so its bootstrap term does too).
    b.step();
    CHECK(std::isfinite(b.snapshot().loss));
    CHECK(b.model().atlas_fg().sizes() == a.model().atlas_fg().sizes());
    // A checkpoint whose track is "flow" (masks as stored, no cleaning) rebuilds from them.
    auto j = nlohmann::json::parse(read_text_file(ck / "checkpoint.json"));
    strip_checksums(j);  // as an earlier build wrote it
    j["subject_track"] = "flow";
    write_file_atomic(ck / "checkpoint.json", j.dump());
    auto data_c = std::make_shared<FitData>(*data_b);
    data_c->mask_as_stored = data->mask.clone();
    FitEngine c(data_c, o);
    c.load_checkpoint(ck);
    CHECK(c.data().legacy_track_gaps);
    CHECK_FALSE(c.data().legacy_subject_track);
    CHECK(torch::equal(c.data().mask, data->mask));
    CHECK(torch::equal(a.render_frame(2).sharp, c.render_frame(2).sharp));
    // A geometry that does not fit the clip is refused with the tensor named.
    auto state = a.model().state();
    state["fg_to_atlas"] = torch::eye(3).expand({2, 3, 3}).clone();
    CHECK_THROWS_WITH_AS(b.model().load_state(state), doctest::Contains("fg atlas"), Error);
}

TEST_CASE("preparation on a proxy: scaled up, it matches the full-size preparation") {
    // A pan at 256x144 prepared on its 128x72 proxy and at full size: the homographies, the
    // flow and the radius, both against each other and the radius against the truth.
    TinyClip c = make_tiny("fit_proxy_prepare", "pan", "256x144");
    const Project p = Project::load(c.project);
    auto logged = [](const PrepareLog& l, const std::string& s) {
        for (const auto& line : l.lines())
            if (line.find(s) != std::string::npos) return true;
        return false;
    };
    FitSetupOptions full_opts, proxy_opts;
    full_opts.proxy_width = 0;
    proxy_opts.proxy_width = 128;
    PrepareLog log_full, log_proxy, log_again;
    auto full = build_fit_data(p, full_opts, log_full);
    auto proxy = build_fit_data(p, proxy_opts, log_proxy);
    CHECK_FALSE(logged(log_full, "proxies"));
    CHECK(logged(log_proxy, "on 128x72 proxies"));
    CHECK_FALSE(logged(log_proxy, "prepare: reusing"));  // another size: prepared again
    REQUIRE(proxy->radius.sizes() == full->radius.sizes());
    REQUIRE(proxy->input.sizes() == full->input.sizes());
    CHECK(torch::equal(proxy->input, full->input));  // the fit still sees every pixel
    CHECK(proxy->static_camera == full->static_camera);

    // Homographies: the frame corners' disagreement, px at full size.
    double worst = 0;
    for (int t = 0; t < p.frames; ++t) {
        auto a = full->to_ref[t], b = proxy->to_ref[t];
        for (double x : {0.0, 255.0})
            for (double y : {0.0, 143.0}) {
                auto v = torch::tensor({x, y, 1.0}, torch::kFloat64);
                auto pa = a.matmul(v), pb = b.matmul(v);
                pa = pa / pa[2], pb = pb / pb[2];
                worst = std::max(worst, (pa - pb).narrow(0, 0, 2).norm().item<double>());
            }
    }
    // Flow: median end-point disagreement where both are consistent.
    auto both = (full->flow_valid > 0.5) & (proxy->flow_valid > 0.5);
    auto epe = (full->flow_fwd - proxy->flow_fwd).norm(2, 1, true).masked_select(both);
    const double flow_median = epe.numel() ? epe.median().item<double>() : 1e9;
    // Radius against the truth.
    std::vector<Image> truth;
    for (int t = 0; t < p.frames; ++t)
        truth.push_back(
            read_image_file((c.clip / format_pattern("coc_%04d.exr", t)).string(), false).image);
    const auto gt = stack_images(truth).squeeze(1);
    const double err_full = (full->radius - gt).abs().mean().item<double>();
    const double err_proxy = (proxy->radius - gt).abs().mean().item<double>();
    MESSAGE("pan 256x144 on a 128x72 proxy: corners within "
            << worst << " px of the full-size "
            << "homographies, flow median end-point difference " << flow_median << " px ("
            << epe.numel() << " px consistent in both), radius mean |error| " << err_proxy
            << " px (full size " << err_full << " px)");
    CHECK(worst < 1.5);
    CHECK(flow_median < 0.5);
    CHECK(err_proxy < err_full + 1.0);

    // The same proxy width reuses the preparation; its result is the same.
    auto again = build_fit_data(p, proxy_opts, log_again);
    CHECK(logged(log_again, "prepare: reusing"));
    CHECK(torch::allclose(again->radius, proxy->radius, 1e-5, 1e-5));
    CHECK(torch::equal(again->to_ref, proxy->to_ref));
}

TEST_CASE("a clip over fit.memory_mb streams its arrays through file mappings: the same fit") {
    // The hunt clip with the budget at 0 MB: every per-frame array is a file mapping, trimmed
    // from memory as the fit goes, and the fit is bit for bit the one in memory.
    TinyClip c = make_tiny("fit_mapped_arrays", "hunt", "96x54");
    const Project p = Project::load(c.project);
    FitSetupOptions in_memory, mapped;
    mapped.memory_mb = 0;
    PrepareLog log_a, log_b;
    auto a = build_fit_data(p, in_memory, log_a);
    auto b = build_fit_data(p, mapped, log_b);
    CHECK_FALSE(is_mapped(a->input));
    REQUIRE(is_mapped(b->input));
    CHECK(is_mapped(b->radius));
    CHECK(mapped_bytes() >= int64_t(b->input.numel() * 4));
    CHECK(torch::equal(a->input, b->input));
    CHECK(torch::equal(a->radius, b->radius));
    CHECK(torch::equal(a->to_ref, b->to_ref));
    REQUIRE(a->has_subject == b->has_subject);
    if (a->has_subject) {
        CHECK(is_mapped(b->mask));
        CHECK(torch::equal(a->mask, b->mask));
    }
    REQUIRE(a->flow_fwd.defined() == b->flow_fwd.defined());
    if (a->flow_fwd.defined()) CHECK(torch::equal(a->flow_fwd, b->flow_fwd));
    FitOptions o;
    o.preset = "fast";
    o.iters = 6;
    o.seed = 3;
    FitEngine ea(a, o), eb(b, o);
    for (int i = 0; i < 6; ++i) {
        ea.step();
        eb.step();
        trim_mapped();  // pages dropped between steps come back from the file
    }
    for (int t : {0, 7}) CHECK(torch::equal(ea.render_frame(t).sharp, eb.render_frame(t).sharp));
    bool said = false;
    for (const auto& line : log_b.lines()) said |= line.find("fit.memory_mb") != std::string::npos;
    CHECK(said);
    // A folder that cannot hold the working file is named.
    CHECK_THROWS_WITH_AS(mapped_tensor({4, 4}, "/proc/refocus-cannot-be-here"),
                         doctest::Contains("/proc/refocus-cannot-be-here"), Error);
}

TEST_CASE("a fitted project opens from its checkpoint without aligning again: the same frames") {
    // A moving camera, where the set-up's ECC alignment has work to do. open_fitted skips it
    // when the checkpoint holds the geometry; without per-tensor checksums (an older checkpoint)
    // it runs the full set-up. Both exports must be the same picture.
    TinyClip c = make_tiny("open_fitted_geometry", "pan", "160x90");
    auto r = cli("fit '" + c.project.string() + "' --iters 30");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const std::vector<Image> skipped = export_sharp(c, "skipped");
    const fs::path ck = c.project / "fit" / "checkpoint.json";
    nlohmann::json j = nlohmann::json::parse(read_text_file(ck));
    REQUIRE(j.contains("checksums"));
    REQUIRE(j["checksums"].contains("model/bg_to_atlas"));
    strip_checksums(j);
    write_file_atomic(ck, j.dump(1));
    const std::vector<Image> full = export_sharp(c, "full");
    REQUIRE(skipped.size() == full.size());
    for (size_t t = 0; t < full.size(); ++t) {
        INFO("frame " << t);
        CHECK(psnr(skipped[t], full[t]) > 60.0);
    }
}

namespace {
bool said(const PrepareLog& l, const std::string& s) {
    for (const auto& line : l.lines())
        if (line.find(s) != std::string::npos) return true;
    return false;
}
}  // namespace

TEST_CASE("a long clip keeps its arrays for the next command: the same data, the same fit") {
    // The budget at 0 MB makes every clip "long": its arrays stream through file mappings and
    // are kept in work/clip/ (model/clip_cache.h). The next opening maps them instead of making
    // them again, and must give the data and the fit bit for bit.
    TinyClip c = make_tiny("clip_cache", "rack", "160x90");
    const Project p = Project::load(c.project);
    FitSetupOptions mapped;
    mapped.memory_mb = 0;
    PrepareLog log_a, log_b;
    auto a = build_fit_data(p, mapped, log_a);
    const fs::path kept = c.project / "work" / "clip";
    REQUIRE(fs::exists(kept / "clip.json"));
    CHECK_FALSE(said(log_a, "as the last command kept them"));
    auto b = build_fit_data(p, mapped, log_b);
    INFO(log_b.lines().back());
    CHECK(said(log_b, "as the last command kept them"));
    CHECK(b->input_finite);
    CHECK(b->radius_finite);
    CHECK(torch::equal(a->input, b->input));
    CHECK(torch::equal(a->radius, b->radius));
    CHECK(torch::equal(a->to_ref, b->to_ref));
    CHECK(a->static_camera == b->static_camera);
    CHECK(a->fixed_focus_share == b->fixed_focus_share);
    CHECK(a->atlas_scale == b->atlas_scale);
    REQUIRE(a->has_subject == b->has_subject);
    REQUIRE(a->has_subject);  // walkout: the subject's masks, its track and its layer radius
    CHECK(torch::equal(a->mask, b->mask));
    REQUIRE(a->flow_fwd.defined() == b->flow_fwd.defined());
    if (a->flow_fwd.defined()) CHECK(torch::equal(a->flow_fwd, b->flow_fwd));
    // The kept track is the one the masks and flow give.
    std::vector<double> ax, ay, as, bx, by, bs;
    subject_track(*b, bx, by, &bs);
    FitData fresh = *b;
    fresh.track_memo.clear();
    subject_track(fresh, ax, ay, &as);
    CHECK(ax == bx);
    CHECK(ay == by);
    CHECK(as == bs);
    // Kept arrays are mapped read-only: nothing of this command writes into another's.
    CHECK(is_mapped(b->input));
    FitOptions o;
    o.preset = "fast";
    o.iters = 5;
    o.seed = 3;
    FitEngine ea(a, o), eb(b, o);
    REQUIRE(fs::exists(kept / "radius_fg.json"));
    CHECK(torch::equal(a->radius_fg, b->radius_fg));
    CHECK(torch::equal(a->radius_bg, b->radius_bg));
    for (int i = 0; i < 5; ++i) {
        ea.step();
        eb.step();
    }
    for (int t : {0, 7}) CHECK(torch::equal(ea.render_frame(t).sharp, eb.render_frame(t).sharp));

    // Other data, or a damaged file, make them again.
    FitSetupOptions other = mapped;
    other.settings.set("radius.floor_max", "50");
    PrepareLog log_c;
    build_fit_data(p, other, log_c);
    CHECK_FALSE(said(log_c, "as the last command kept them"));
    fs::resize_file(kept / "input.f32", 1000);
    PrepareLog log_d;
    auto d = build_fit_data(p, other, log_d);
    CHECK_FALSE(said(log_d, "as the last command kept them"));
    CHECK(torch::equal(d->input, a->input));
    // fit.clip_cache 0: nothing kept, nothing read.
    fs::remove_all(kept);
    FitSetupOptions off = mapped;
    off.clip_cache = false;
    PrepareLog log_e;
    build_fit_data(p, off, log_e);
    CHECK_FALSE(fs::exists(kept / "clip.json"));
}

TEST_CASE("a fitted long clip exports the same frames from its kept arrays as made again") {
    TinyClip c = make_tiny("clip_cache_export", "rack", "160x90");
    auto r = cli("fit '" + c.project.string() + "' --iters 12 --set fit.memory_mb=0");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const fs::path manifest = c.project / "work" / "clip" / "clip.json";
    REQUIRE(fs::exists(manifest));
    const auto kept_at = fs::last_write_time(manifest);
    const std::vector<Image> kept = export_sharp(c, "kept");
    CHECK(fs::last_write_time(manifest) == kept_at);  // opened from them, not made again
    fs::remove_all(c.project / "work" / "clip");
    const std::vector<Image> made = export_sharp(c, "made");
    CHECK(fs::exists(manifest));  // made again, and kept
    REQUIRE(kept.size() == made.size());
    for (size_t t = 0; t < made.size(); ++t) CHECK(max_abs_diff(kept[t], made[t]) == 0.0);
}
