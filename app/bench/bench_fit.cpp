// refocus bench fit: run time against error on a `refocus synth` clip with ground truth.
#include <cstdio>
#include <fstream>
#include <sstream>

#include "args.h"
#include "bench_eval.h"
#include "commands.h"
#include "fit/settings.h"
#include "session/fit_session.h"
#include "metrics/metrics.h"
#include "util/error.h"

namespace refocus {

namespace {

// Where the sharp output's error lies in spatial frequency, beside the input's (metrics.h,
// error_by_band): what a band's error is made of tells a prior's shrinkage (gain under 1 where
// the blur passed the band) from what the input never held.
void print_bands(const EvalFrames& f) {
    const std::vector<double> edges{0, .02, .04, .06, .08, .1, .13, .16, .2, .25, .3, .4, .5, .71};
    const auto out = error_by_band(f.sharp, f.gt, edges), in = error_by_band(f.input, f.gt, edges);
    std::printf(
        "error by spatial frequency (cycles/px; power sums over frames and channels, sRGB 8-bit "
        "levels, Hann window):\n");
    std::printf("%11s %12s %12s %7s %7s %12s %7s\n", "band", "truth power", "error", "share",
                "gain", "input error", "gain");
    for (size_t i = 0; i < out.size(); ++i)
        std::printf("  %.2f-%.2f %12.4g %12.4g %6.1f%% %7.3f %12.4g %7.3f\n", out[i].lo, out[i].hi,
                    out[i].gt_power, out[i].err_power, 100 * out[i].err_share, out[i].gain,
                    in[i].err_power, in[i].gain);
}

std::vector<double> parse_times(const std::string& s) {
    std::vector<double> v;
    std::stringstream ss(s);
    std::string item;
    while (std::getline(ss, item, ',')) v.push_back(std::stod(item));
    return v;
}

// --score <project>: no fit; the fitted project's sharp output, as `refocus export` writes it
// at the project's settings now, scored against the clip's truth. Re-scores a checkpoint after a
// change to the output rules, which act at export and not on the fit. `sets` (--set) change
// the project's settings in memory only: the output rules' (fit.*) compare on one checkpoint;
// project.json is not written.
int score_fitted(const fs::path& clip, const fs::path& dir, const std::vector<std::string>& sets) {
    Project project = Project::load(dir);
    if (!sets.empty()) {
        auto& fit = project.sections["fit"];
        Settings settings;
        if (fit.contains("settings"))
            settings.set_json(fit["settings"], project.project_file().string() + ": fit.settings");
        for (const auto& assignment : sets) settings.set_assignment(assignment);
        fit["settings"] = settings.to_json();
    }
    PrepareLog log([](const std::string& l) { std::fprintf(stderr, "  %s\n", l.c_str()); });
    auto engine = open_fitted(project, log);
    std::vector<Image> gt = read_all_frames((clip / "sharp_%04d.png").string());
    if (int(gt.size()) < project.frames)
        throw Error(file_error((clip / "sharp_%04d.png").string(),
                               "holds " + std::to_string(gt.size()) + " frames, the project " +
                                   std::to_string(project.frames)));
    gt.resize(project.frames);
    std::vector<Image> input;
    for (int t = 0; t < project.frames; ++t) input.push_back(project.read_frame(t));
    EvalFrames last;
    const EvalRow r = evaluate(*engine, gt, input, &last);
    std::printf("project %s against %s (%d frames), step %lld\n", dir.string().c_str(),
                clip.string().c_str(), project.frames, (long long)r.step);
    std::printf("input vs ground truth: PSNR %.2f dB  SSIM %.4f  tPSNR %.2f dB\n", r.in_psnr,
                r.in_ssim, r.in_tpsnr);
    std::printf("sharp output:          PSNR %.2f dB  SSIM %.4f  tPSNR %.2f dB  reblur PSNR %.2f\n",
                r.psnr, r.ssim, r.tpsnr, r.reblur_psnr);
    std::printf("gain over input: %+.2f dB PSNR, %+.2f dB tPSNR\n", r.psnr - r.in_psnr,
                r.tpsnr - r.in_tpsnr);
    std::printf("residual: RMS %.2f levels, noise %.2f levels, model trusted %.2f\n",
                engine->residual_rms(), engine->data().noise_levels, engine->model_trust());
    if (!last.model.empty() && last.model.size() == last.sharp.size()) {
        // What the rules keep of the model (bench corpus's yardstick): the plate alone, the
        // oracle blend, the worst frame and the share of the oracle's gain the output captures.
        double model = 0, oracle = 0, worst = 1e9;
        const double n = double(last.model.size());
        for (size_t i = 0; i < last.model.size(); ++i) {
            const double in = psnr(last.input[i], last.gt[i]);
            model += psnr(last.model[i], last.gt[i]) / n;
            oracle += oracle_blend_psnr(last.model[i], last.input[i], last.gt[i]) / n;
            worst = std::min(worst, psnr(last.sharp[i], last.gt[i]) - in);
        }
        const double gain = r.psnr - r.in_psnr, og = oracle - r.in_psnr;
        std::printf("model alone %+.2f dB, oracle blend %+.2f dB, worst frame %+.2f dB",
                    model - r.in_psnr, og, worst);
        if (og >= 0.5) std::printf(", captured %.0f %%", 100.0 * gain / og);
        std::printf("\n");
    }
    if (!last.sharp.empty()) print_bands(last);
    return 0;
}

}  // namespace

int bench_fit(int argc, char** argv) {
    Args a(argc, argv, 3, {"oracle-coc", "oracle-mask"});
    a.check_known({"clip", "preset", "minutes", "iters", "oracle-coc", "coc", "oracle-mask", "mask",
                   "at", "csv", "work", "seed", "batch", "set", "score"});
    if (!a.has("clip"))
        throw Error(
            "usage: refocus bench fit --clip <synth-dir> --preset " + preset_names() +
            " "
            "[--minutes M] [--oracle-coc | --coc <pattern>] [--oracle-mask | --mask <pattern>] "
            "[--at 0.5,1,2,5,10] [--csv out.csv] [--batch N] [--set name=value]...");
    const fs::path clip = a.get("clip");
    if (!fs::exists(clip / "clip.json"))
        throw Error(file_error(clip.string(), "not a refocus synth clip (no clip.json)"));
    if (a.has("score")) return score_fitted(clip, a.get("score"), a.get_all("set"));
    const std::string preset = a.get("preset", "fast");
    const double minutes = a.get_double("minutes", 10.0);
    const bool oracle = a.has("oracle-coc");
    const fs::path work = a.get(
        "work",
        (fs::temp_directory_path() / ("refocus_bench_" + clip.filename().string() + "_" + preset))
            .string());
    fs::remove_all(work);
    Project project = create_project((clip / "input_%04d.png").string(), work, {});
    std::vector<Image> gt = read_all_frames((clip / "sharp_%04d.png").string());
    std::vector<Image> input;
    for (int t = 0; t < project.frames; ++t) input.push_back(project.read_frame(t));

    FitSettings s = bench_fit_settings(a, preset, minutes);
    if (oracle) s.setup.coc_path = (clip / "coc_%04d.exr").string();
    if (a.has("coc"))
        s.setup.coc_path = a.get("coc");  // radius maps to try (e.g. the truth scaled)
    const bool oracle_mask = a.has("oracle-mask");
    if (oracle_mask) s.setup.mask_path = (clip / "alpha_%04d.png").string();
    if (a.has("mask"))
        s.setup.mask_path = a.get("mask");  // masks to try (e.g. bench motion --dump)
    PrepareLog log([](const std::string& l) { std::fprintf(stderr, "  %s\n", l.c_str()); });
    auto data = build_fit_data(project, s.setup, log);
    FitEngine engine(data, s.fit);
    for (const auto& line : engine.model_notes()) log.info(line);

    std::vector<double> at = parse_times(a.get("at", "0.5,1,2,5,10,20,30"));
    std::vector<EvalRow> rows;
    const double in_psnr = mean_psnr(input, gt), in_ssim = mean_ssim(input, gt);
    const double in_t = gt.size() > 1 ? tpsnr(input, gt) : 0.0;
    std::printf("clip %s (%dx%d, %d frames), preset %s, radius %s, masks %s\n",
                clip.string().c_str(), project.width, project.height, project.frames,
                preset.c_str(),
                oracle         ? "ground truth (--coc)"
                : a.has("coc") ? a.get("coc").c_str()
                               : "estimated",
                oracle_mask     ? "ground-truth alpha (--mask)"
                : a.has("mask") ? a.get("mask").c_str()
                                : "automatic");
    std::printf("input vs ground truth: PSNR %.2f dB  SSIM %.4f  tPSNR %.2f dB\n", in_psnr, in_ssim,
                in_t);
    std::printf("%8s %7s %9s %7s %9s %12s %7s\n", "minutes", "step", "PSNR", "SSIM", "tPSNR",
                "reblur PSNR", "frames");
    size_t next = 0;
    while (!engine.done()) {
        engine.step();
        const double el = engine.snapshot().elapsed_s / 60.0;
        if (next < at.size() && el >= at[next]) {
            while (next < at.size() && el >= at[next]) ++next;
            rows.push_back(evaluate(engine, gt, input));
            const EvalRow& r = rows.back();
            std::printf("%8.2f %7lld %9.2f %7.4f %9.2f %12.2f %4d/%d\n", r.minutes,
                        (long long)r.step, r.psnr, r.ssim, r.tpsnr, r.reblur_psnr, r.frames_done,
                        project.frames);
            std::fflush(stdout);
        }
    }
    EvalFrames last;
    rows.push_back(evaluate(engine, gt, input, &last));
    // Keep the result: `refocus export <work>` shows what the figures measured.
    engine.save_checkpoint(fit_dir(project));
    FitSnapshot snap = engine.snapshot();
    write_fit_settings(project, s, &snap);
    const EvalRow& r = rows.back();
    std::printf("%8.2f %7lld %9.2f %7.4f %9.2f %12.2f %4d/%d (end)\n", r.minutes, (long long)r.step,
                r.psnr, r.ssim, r.tpsnr, r.reblur_psnr, r.frames_done, project.frames);
    std::printf("fitted project kept in %s\n", work.string().c_str());
    if (r.frames_done < project.frames)
        std::printf(
            "only %d of %d frames done: figures on those frames; input there: PSNR %.2f dB  "
            "SSIM %.4f  tPSNR %.2f dB\n",
            r.frames_done, project.frames, r.in_psnr, r.in_ssim, r.in_tpsnr);
    std::printf("gain over input: %+.2f dB PSNR, %+.2f dB tPSNR\n", r.psnr - r.in_psnr,
                r.tpsnr - r.in_tpsnr);
    if (!last.sharp.empty()) print_bands(last);
    if (a.has("csv")) {
        std::ostringstream csv;
        csv << "clip,preset,radius,minutes,step,psnr,ssim,tpsnr,reblur_psnr,input_psnr,input_tpsnr,"
               "frames_done,input_ssim\n";
        for (const EvalRow& x : rows)
            csv << clip.filename().string() << "," << preset << ","
                << (oracle         ? "oracle"
                    : a.has("coc") ? "given"
                                   : "estimated")
                << (oracle_mask ? "+mask" : "") << "," << x.minutes << "," << x.step << ","
                << x.psnr << "," << x.ssim << "," << x.tpsnr << "," << x.reblur_psnr << ","
                << x.in_psnr << "," << x.in_tpsnr << "," << x.frames_done << "," << x.in_ssim
                << "\n";
        write_file_atomic(a.get("csv"), csv.str());
    }
    return 0;
}

}  // namespace refocus
