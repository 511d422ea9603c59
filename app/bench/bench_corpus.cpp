// refocus bench corpus <dir>: every clip of a corpus (folders laid out as `refocus synth` writes
// them, with clip.json's "split") fitted as `bench fit` does, scored in one table and a CSV.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "args.h"
#include "bench_eval.h"
#include "commands.h"
#include "fit/presets.h"
#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "bench/views_bound.h"
#include "util/error.h"
#include "util/json_file.h"

namespace refocus {

namespace {

const double kNaN = std::numeric_limits<double>::quiet_NaN();

struct CorpusClip {
    fs::path dir;
    std::string name, split;
    int frames = 0, width = 0, height = 0;
    bool has_alpha = false;  // alpha_%04d.png for every frame
};

struct ClipResult {
    EvalRow row;
    double worst_gain = 0;  // the lowest per-frame output PSNR less input PSNR
    int worst_frame = -1;
    // Mean over frames of the PSNR inside / outside the subject's mask; NaN without a mask.
    double in_inside = kNaN, out_inside = kNaN, in_outside = kNaN, out_outside = kNaN;
    // Colour shift: the largest channel's |mean − the truth's mean| over the scored frames, in
    // 8-bit sRGB codes (#35's target on a clip already in focus: 0.5).
    double in_shift = kNaN, out_shift = kNaN;
    // The output rules' yardstick (#51): the clip's measured noise (levels), the model's plate
    // alone and the oracle blend (bench_eval.h), mean PSNR over the scored frames.
    double noise = kNaN, model_psnr = kNaN, oracle_psnr = kNaN;
    // The radius estimate against the clip's true coc: median and 90th percentile of |r^ - r|
    // (px) inside and outside the subject's mask (outside: every pixel without a mask).
    double rad_med_in = kNaN, rad_p90_in = kNaN, rad_med_out = kNaN, rad_p90_out = kNaN;
};

std::string pass_file(const fs::path& dir, const char* pass, int t, const char* ext) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%s_%04d.%s", pass, t, ext);
    return (dir / buf).string();
}
std::string pass_pattern(const fs::path& dir, const char* pass, const char* ext) {
    return (dir / (std::string(pass) + "_%04d." + ext)).string();
}

// The folder's clips of `split` (dev, val or all), sorted by folder name, each checked before
// any fit: a bad clip fails the run at once, not hours into it.
std::vector<CorpusClip> list_clips(const fs::path& dir, const std::string& split, bool oracle) {
    if (!fs::is_directory(dir)) throw Error(file_error(dir.string(), "not a folder"));
    std::vector<fs::path> folders;
    for (const auto& e : fs::directory_iterator(dir))
        if (e.is_directory() && fs::exists(e.path() / "clip.json")) folders.push_back(e.path());
    std::sort(folders.begin(), folders.end());
    if (folders.empty())
        throw Error(file_error(dir.string(), "no clip folders (folders holding a clip.json)"));
    std::vector<CorpusClip> clips;
    std::map<std::string, int> per_split;
    for (const fs::path& f : folders) {
        const std::string json_path = (f / "clip.json").string();
        const nlohmann::json j = read_json_file(json_path);
        CorpusClip c;
        c.dir = f;
        c.name = j.contains("name") && j["name"].is_string() ? j["name"].get<std::string>()
                                                             : f.filename().string();
        c.split = "dev";  // `refocus synth` clips carry no split
        if (j.contains("split")) {
            if (!j["split"].is_string() || (j["split"] != "dev" && j["split"] != "val"))
                throw Error(file_error(json_path, "\"split\" must be \"dev\" or \"val\""));
            c.split = j["split"].get<std::string>();
        }
        ++per_split[c.split];
        if (split == "all" || c.split == split) clips.push_back(c);
    }
    if (clips.empty())
        throw Error(file_error(dir.string(), "no clips in split '" + split + "' (" +
                                                 std::to_string(per_split["dev"]) + " dev, " +
                                                 std::to_string(per_split["val"]) + " val)"));
    for (CorpusClip& c : clips) {
        const ClipInfo in = ClipReader::open(pass_pattern(c.dir, "input", "png"))->info();
        const std::string sharp = pass_pattern(c.dir, "sharp", "png");
        if (!fs::exists(pass_file(c.dir, "sharp", 0, "png")))
            throw Error(file_error(sharp, "no ground-truth frames"));
        const ClipInfo gt = ClipReader::open(sharp)->info();
        if (gt.frames != in.frames)
            throw Error(file_error(sharp, std::to_string(gt.frames) + " frames, but " +
                                              std::to_string(in.frames) + " input frames"));
        if (gt.width != in.width || gt.height != in.height)
            throw Error(file_error(sharp, "frames differ in size from the input's"));
        c.frames = in.frames;
        c.width = in.width;
        c.height = in.height;
        c.has_alpha = fs::exists(pass_file(c.dir, "alpha", 0, "png"));
        for (int t = 0; t < c.frames; ++t) {
            if (c.has_alpha && !fs::exists(pass_file(c.dir, "alpha", t, "png")))
                throw Error(file_error(pass_file(c.dir, "alpha", t, "png"), "missing"));
            if (oracle && !fs::exists(pass_file(c.dir, "coc", t, "exr")))
                throw Error(
                    file_error(pass_file(c.dir, "coc", t, "exr"), "missing (--oracle-coc)"));
        }
    }
    return clips;
}

// Removes the scratch project however the fit ends.
struct ScratchDir {
    fs::path path;
    ~ScratchDir() {
        std::error_code ec;
        fs::remove_all(path, ec);
    }
};

// The per-frame and masked figures on the frames the evaluation scored.
void score_frames(const CorpusClip& c, const EvalFrames& f, ClipResult& r) {
    r.worst_gain = kNaN;     // no frame done
    double chan[3][3] = {};  // [truth, input, output][channel] sums, 8-bit codes
    size_t count = 0;
    for (size_t i = 0; i < f.sharp.size(); ++i) {
        const double gain = psnr(f.sharp[i], f.gt[i]) - psnr(f.input[i], f.gt[i]);
        if (i == 0 || gain < r.worst_gain) r.worst_gain = gain, r.worst_frame = f.index[i];
        const Image* imgs[3] = {&f.gt[i], &f.input[i], &f.sharp[i]};
        for (int k = 0; k < 3; ++k) {
            const Image e = to_metric_space(*imgs[k]);
            for (size_t p = 0; p < e.pixels.size(); ++p) chan[k][p % e.channels] += e.pixels[p];
        }
        count += size_t(f.gt[i].width) * f.gt[i].height;
    }
    if (count > 0 && f.gt[0].channels >= 3) {
        r.in_shift = r.out_shift = 0;
        for (int ch = 0; ch < 3; ++ch) {
            r.in_shift = std::max(r.in_shift, std::abs(chan[1][ch] - chan[0][ch]) / count);
            r.out_shift = std::max(r.out_shift, std::abs(chan[2][ch] - chan[0][ch]) / count);
        }
    }
    if (!c.has_alpha) return;
    double sum[4] = {0, 0, 0, 0};
    int n[2] = {0, 0};  // frames with pixels inside, outside
    for (size_t i = 0; i < f.sharp.size(); ++i) {
        const std::string path = pass_file(c.dir, "alpha", f.index[i], "png");
        const Image mask = read_image_file(path, false).image;  // data, not sRGB
        if (mask.width != c.width || mask.height != c.height)
            throw Error(file_error(path, "mask size differs from the frames'"));
        const MaskRegion regions[2] = {MaskRegion::Inside, MaskRegion::Outside};
        for (int k = 0; k < 2; ++k) {
            const double in = masked_psnr(f.input[i], f.gt[i], mask, regions[k]);
            if (std::isnan(in)) continue;
            sum[2 * k] += in;
            sum[2 * k + 1] += masked_psnr(f.sharp[i], f.gt[i], mask, regions[k]);
            ++n[k];
        }
    }
    if (n[0] == 0) return;  // an empty mask: no inside/outside split
    r.in_inside = sum[0] / n[0];
    r.out_inside = sum[1] / n[0];
    if (n[1] > 0) r.in_outside = sum[2] / n[1], r.out_outside = sum[3] / n[1];
}

// The oracle blend and the model's plate alone, mean PSNR over the scored frames.
void score_oracle(const EvalFrames& f, ClipResult& r) {
    if (f.model.empty()) return;
    double m = 0, o = 0;
    for (size_t i = 0; i < f.model.size(); ++i) {
        m += std::min(100.0, psnr(f.model[i], f.gt[i]));
        o += oracle_blend_psnr(f.model[i], f.input[i], f.gt[i]);
    }
    r.model_psnr = m / double(f.model.size());
    r.oracle_psnr = o / double(f.model.size());
}

// |r^ - r| over the clip (the fit's radius maps against coc_%04d.exr), split by the mask.
void score_radius(const CorpusClip& c, const FitEngine& engine, ClipResult& r) {
    const torch::Tensor& est = engine.data().radius;  // [T,H,W] px
    if (!est.defined() || !fs::exists(pass_file(c.dir, "coc", 0, "exr"))) return;
    std::vector<float> in, out;
    for (int t = 0; t < c.frames; t += std::max(1, c.frames / 10)) {
        const Image truth = read_image_file(pass_file(c.dir, "coc", t, "exr"), false).image;
        if (truth.width != c.width || truth.height != c.height) continue;
        Image mask;
        if (c.has_alpha) mask = read_image_file(pass_file(c.dir, "alpha", t, "png"), false).image;
        const torch::Tensor e = est[t].contiguous().to(torch::kFloat32);
        const float* ep = e.data_ptr<float>();
        for (int p = 0; p < c.width * c.height; ++p) {
            const float d = std::abs(ep[p] - truth.pixels[size_t(p) * truth.channels]);
            const bool inside = c.has_alpha && mask.pixels[size_t(p) * mask.channels] >= 0.5f;
            (inside ? in : out).push_back(d);
        }
    }
    auto q = [](std::vector<float>& v, double share) {
        if (v.empty()) return kNaN;
        const size_t k = std::min(v.size() - 1, size_t(share * double(v.size())));
        std::nth_element(v.begin(), v.begin() + k, v.end());
        return double(v[k]);
    };
    r.rad_med_in = q(in, 0.5), r.rad_p90_in = q(in, 0.9);
    r.rad_med_out = q(out, 0.5), r.rad_p90_out = q(out, 0.9);
}

// Fits one clip in a scratch project under the system's temp folder and scores it.
ClipResult fit_clip(const CorpusClip& c, FitSettings s, bool oracle, const std::string& label) {
    ScratchDir work{make_temp_dir_beside(fs::temp_directory_path() /
                                         ("refocus_bench_corpus_" + c.dir.filename().string()))};
    const std::string input_pattern = pass_pattern(c.dir, "input", "png");
    Project project = create_project(input_pattern, work.path, {});
    const std::vector<Image> input = read_all_frames(input_pattern);
    const std::vector<Image> gt = read_all_frames(pass_pattern(c.dir, "sharp", "png"));
    if (oracle) s.setup.coc_path = pass_pattern(c.dir, "coc", "exr");
    PrepareLog log([](const std::string& l) { std::fprintf(stderr, "    %s\n", l.c_str()); });
    auto data = build_fit_data(project, s.setup, log);
    FitEngine engine(data, s.fit);
    for (const auto& line : engine.model_notes()) log.info(line);
    double next_report = 60;  // a long fit says where it is once a minute
    while (!engine.done()) {
        engine.step();
        const FitSnapshot snap = engine.snapshot();
        if (snap.elapsed_s >= next_report) {
            std::fprintf(stderr, "%s step %lld, %.0f s\n", label.c_str(), (long long)snap.step,
                         snap.elapsed_s);
            next_report += 60;
        }
    }
    ClipResult r;
    EvalFrames frames;
    r.row = evaluate(engine, gt, input, &frames);
    score_frames(c, frames, r);
    score_oracle(frames, r);
    score_radius(c, engine, r);
    r.noise = data->noise_levels >= 0 ? data->noise_levels : kNaN;
    return r;
}

// The targets (#35), each per clip.
struct Targets {
    bool gain, worst, tpsnr, ssim;
    bool all() const { return gain && worst && tpsnr && ssim; }
};
Targets targets_of(const ClipResult& r) {
    return {r.row.psnr >= r.row.in_psnr + 1.0, r.worst_gain >= -0.5, r.row.tpsnr > r.row.in_tpsnr,
            r.row.ssim > r.row.in_ssim};
}

// The table's and the CSV's numeric columns, per clip and as the mean over clips (the target
// columns: 1 met, 0 not; their mean is the share of clips that meet it).
enum Fig {
    kFrames,
    kFramesDone,
    kInPsnr,
    kPsnr,
    kGain,
    kInSsim,
    kSsim,
    kInTpsnr,
    kTpsnr,
    kWorst,
    kInInside,
    kOutInside,
    kInOutside,
    kOutOutside,
    kInShift,
    kOutShift,
    kSteps,
    kSeconds,
    kTargetGain,
    kTargetWorst,
    kTargetTpsnr,
    kTargetSsim,
    kNoise,
    kModelGain,
    kOracleGain,
    kCaptured,
    kRadMedIn,
    kRadP90In,
    kRadMedOut,
    kRadP90Out,
    kFigCount
};
using Figures = std::array<double, kFigCount>;

Figures figures_of(const CorpusClip& c, const ClipResult& r) {
    const EvalRow& x = r.row;
    const Targets t = targets_of(r);
    return {double(c.frames), double(x.frames_done), x.in_psnr, x.psnr, x.psnr - x.in_psnr,
            x.in_ssim, x.ssim, x.in_tpsnr, x.tpsnr, r.worst_gain, r.in_inside, r.out_inside,
            r.in_outside, r.out_outside, r.in_shift, r.out_shift, double(x.step), x.minutes * 60,
            double(t.gain), double(t.worst), double(t.tpsnr), double(t.ssim), r.noise,
            r.model_psnr - x.in_psnr, r.oracle_psnr - x.in_psnr,
            // The share of the oracle blend's gain the output captures, where there is one.
            r.oracle_psnr - x.in_psnr >= 0.5 ? (x.psnr - x.in_psnr) / (r.oracle_psnr - x.in_psnr)
                                             : kNaN,
            r.rad_med_in, r.rad_p90_in, r.rad_med_out, r.rad_p90_out};
}

// The mean of each figure over the clips where it is defined (NaN where it is nowhere).
Figures mean_of(const std::vector<Figures>& all) {
    Figures m{};
    for (int k = 0; k < kFigCount; ++k) {
        double s = 0;
        int n = 0;
        for (const Figures& f : all)
            if (!std::isnan(f[k])) s += f[k], ++n;
        m[k] = n ? s / n : kNaN;
    }
    return m;
}

std::string num(double v, const char* fmt) {
    if (std::isnan(v)) return "-";
    char buf[32];
    std::snprintf(buf, sizeof buf, fmt, v);
    return buf;
}

// Two lines: the column groups (each label over its columns), then the columns.
void print_header(int name_w) {
    std::printf("%*s", name_w + 23, "");
    const std::pair<const char*, int> groups[] = {
        {"PSNR dB (gain)", 20}, {"SSIM", 13},         {"tPSNR dB", 13},     {"worst frame", 12},
        {"inside mask", 13},    {"outside mask", 13}, {"colour shift", 13}, {"fit", 0}};
    for (const auto& [label, width] : groups) std::printf(" | %-*s", width, label);
    std::printf("\n");
    std::printf(
        "%-*s %-5s %6s %9s | %6s %6s %6s | %6s %6s | %6s %6s | %6s %5s | %6s %6s | %6s %6s "
        "| %6s %6s | %6s %7s\n",
        name_w, "clip", "split", "frames", "size", "in", "out", "gain", "in", "out", "in", "out",
        "dB", "frame", "in", "out", "in", "out", "in", "out", "steps", "s");
}

void print_row(int name_w, const std::string& name, const std::string& split,
               const std::string& frames, const std::string& size, const Figures& f,
               const std::string& worst_frame) {
    std::printf(
        "%-*s %-5s %6s %9s | %6s %6s %6s | %6s %6s | %6s %6s | %6s %5s | %6s %6s | %6s %6s | %6s "
        "%6s | %6s %7s\n",
        name_w, name.c_str(), split.c_str(), frames.c_str(), size.c_str(),
        num(f[kInPsnr], "%.2f").c_str(), num(f[kPsnr], "%.2f").c_str(),
        num(f[kGain], "%+.2f").c_str(), num(f[kInSsim], "%.4f").c_str(),
        num(f[kSsim], "%.4f").c_str(), num(f[kInTpsnr], "%.2f").c_str(),
        num(f[kTpsnr], "%.2f").c_str(), num(f[kWorst], "%+.2f").c_str(), worst_frame.c_str(),
        num(f[kInInside], "%.2f").c_str(), num(f[kOutInside], "%.2f").c_str(),
        num(f[kInOutside], "%.2f").c_str(), num(f[kOutOutside], "%.2f").c_str(),
        num(f[kInShift], "%.2f").c_str(), num(f[kOutShift], "%.2f").c_str(),
        num(f[kSteps], "%.0f").c_str(), num(f[kSeconds], "%.1f").c_str());
}

// A CSV field: quoted when it holds a comma or a quote (a clip's name is free text).
std::string csv_field(const std::string& v) {
    if (v.find_first_of(",\"") == std::string::npos) return v;
    std::string q = "\"";
    for (char ch : v) q += ch == '"' ? std::string("\"\"") : std::string(1, ch);
    return q + "\"";
}

// One CSV row: the text columns, then every figure (NaN: empty), then the text tail.
std::string csv_row(const std::string& head, const Figures& f, const std::string& worst_frame,
                    const std::string& tail) {
    std::ostringstream o;
    o << head;
    for (int k = 0; k < kFigCount; ++k) {
        o << ",";
        if (!std::isnan(f[k])) o << num(f[k], "%.6g");
        if (k == kWorst) o << "," << worst_frame;
    }
    o << "," << tail << "\n";
    return o.str();
}

struct Run {
    fs::path dir;
    std::string split, preset, budget;
    bool oracle = false;
};

std::string worst_frame_of(const ClipResult& r) {
    return r.worst_frame < 0 ? "-" : std::to_string(r.worst_frame);
}

// The CSV of the clips fitted so far (`results` holds the first clips' figures) and their mean.
std::string csv_text(const Run& run, const std::vector<CorpusClip>& clips,
                     const std::vector<ClipResult>& results) {
    std::string csv =
        "clip,split,width,height,frames,frames_done,in_psnr,out_psnr,gain_psnr,in_ssim,out_ssim,"
        "in_tpsnr,out_tpsnr,worst_gain,worst_frame,in_psnr_inside,out_psnr_inside,"
        "in_psnr_outside,out_psnr_outside,in_colour_shift,out_colour_shift,steps,fit_s,target_gain,"
        "target_worst,target_tpsnr,"
        "target_ssim,noise_levels,model_gain,oracle_gain,captured,radius_err_med_in,"
        "radius_err_p90_in,radius_err_med_out,radius_err_p90_out,preset,radius\n";
    const std::string tail = run.preset + "," + (run.oracle ? "oracle" : "estimated");
    std::vector<Figures> all;
    for (size_t i = 0; i < results.size(); ++i) {
        const CorpusClip& c = clips[i];
        all.push_back(figures_of(c, results[i]));
        csv += csv_row(csv_field(c.name) + "," + c.split + "," + std::to_string(c.width) + "," +
                           std::to_string(c.height),
                       all.back(), worst_frame_of(results[i]), tail);
    }
    if (!all.empty()) csv += csv_row("mean," + run.split + ",,", mean_of(all), "", tail);
    return csv;
}

// The output rules against the oracle blend, and the radius estimate against the truth.
void print_yardstick(int name_w, const std::vector<CorpusClip>& clips,
                     const std::vector<Figures>& all, const Figures& mean) {
    std::printf("\n%-*s | %6s | %6s %6s %6s %8s | %s\n", name_w, "clip", "noise", "output", "model",
                "oracle", "captured", "radius error px: median / p90 in mask, outside");
    auto row = [&](const std::string& name, const Figures& f) {
        std::printf("%-*s | %6s | %6s %6s %6s %8s | %s / %s, %s / %s\n", name_w, name.c_str(),
                    num(f[kNoise], "%.2f").c_str(), num(f[kGain], "%+.2f").c_str(),
                    num(f[kModelGain], "%+.2f").c_str(), num(f[kOracleGain], "%+.2f").c_str(),
                    num(100 * f[kCaptured], "%.0f%%").c_str(), num(f[kRadMedIn], "%.2f").c_str(),
                    num(f[kRadP90In], "%.2f").c_str(), num(f[kRadMedOut], "%.2f").c_str(),
                    num(f[kRadP90Out], "%.2f").c_str());
    };
    for (size_t i = 0; i < all.size(); ++i) row(clips[i].name, all[i]);
    row("mean", mean);
    std::printf(
        "noise: measured sigma (8-bit levels); output, model, oracle: PSNR gain over the input of "
        "the output as exported, of the model's plate alone (no output rule), and of the oracle "
        "blend (per pixel the better of input and model, chosen with the truth); captured: "
        "output gain / oracle gain where that is >= 0.5 dB\n");
}

void print_table(const Run& run, const std::vector<CorpusClip>& clips,
                 const std::vector<ClipResult>& results) {
    int name_w = 4;
    for (const auto& c : clips) name_w = std::max(name_w, static_cast<int>(c.name.size()));
    std::printf("corpus %s, split %s, preset %s, radius %s, %s\n", run.dir.string().c_str(),
                run.split.c_str(), run.preset.c_str(),
                run.oracle ? "ground truth (--oracle-coc)" : "estimated", run.budget.c_str());
    print_header(name_w);
    std::vector<Figures> all;
    int met[5] = {0, 0, 0, 0, 0};
    for (size_t i = 0; i < clips.size(); ++i) {
        const CorpusClip& c = clips[i];
        const EvalRow& r = results[i].row;
        all.push_back(figures_of(c, results[i]));
        const std::string frames = r.frames_done < c.frames ? std::to_string(r.frames_done) + "/" +
                                                                  std::to_string(c.frames)
                                                            : std::to_string(c.frames);
        print_row(name_w, c.name, c.split, frames,
                  std::to_string(c.width) + "x" + std::to_string(c.height), all.back(),
                  worst_frame_of(results[i]));
        const Targets t = targets_of(results[i]);
        met[0] += t.gain, met[1] += t.worst, met[2] += t.tpsnr, met[3] += t.ssim, met[4] += t.all();
    }
    const Figures mean = mean_of(all);
    print_row(name_w, "mean", run.split, num(mean[kFrames], "%.1f"), "", mean, "");
    std::printf(
        "targets met by %d of %d clips: out >= in + 1 dB %d, worst frame >= -0.5 dB %d, tPSNR "
        "out > in %d, SSIM out > in %d\n",
        met[4], int(clips.size()), met[0], met[1], met[2], met[3]);
    std::printf(
        "worst frame: the lowest per-frame output PSNR less input PSNR; inside/outside mask: PSNR "
        "over the pixels where the clip's alpha is >= 0.5 / < 0.5; 100 dB: exact (the cap)\n");
    print_yardstick(name_w, clips, all, mean);
}

// --views: no fit; each clip's sharpest-view bound (views_bound.h), a table and a CSV.
void print_views(const fs::path& dir, const std::string& split,
                 const std::vector<CorpusClip>& clips, const std::string& csv_path) {
    int name_w = 4;
    for (const auto& c : clips) name_w = std::max(name_w, static_cast<int>(c.name.size()));
    std::printf("corpus %s, split %s: the sharpest-view bound (true depth, cameras and radius)\n",
                dir.string().c_str(), split.c_str());
    std::printf("%-*s %-5s | %6s %6s | %6s %6s %6s | %6s %6s %6s | %6s %6s %6s | %7s\n", name_w,
                "clip", "split", "in", "tPSNR", "least", "gain", "worst", "near", "gain", "worst",
                "tPSNR", "least", "near", "sharper");
    std::string csv =
        "clip,split,in_psnr,in_tpsnr,least_psnr,least_worst,least_tpsnr,near_psnr,near_worst,"
        "near_tpsnr,sharper_share\n";
    std::array<double, 10> mean{};
    for (const CorpusClip& c : clips) {
        std::fprintf(stderr, "%s: the sharpest-view bound\n", c.name.c_str());
        const ViewsBound b = sharpest_view_bound(c.dir);
        const std::array<double, 10> v = {
            b.in_psnr,   b.in_tpsnr,   b.least_psnr, b.least_worst,         b.least_tpsnr,
            b.near_psnr, b.near_worst, b.near_tpsnr, b.sharper_share * 100, 0};
        for (size_t k = 0; k < v.size(); ++k) mean[k] += v[k] / clips.size();
        std::printf(
            "%-*s %-5s | %6.2f %6.2f | %6.2f %+6.2f %+6.2f | %6.2f %+6.2f %+6.2f | %6.2f %6.2f "
            "%6.2f | %6.1f%%\n",
            name_w, c.name.c_str(), c.split.c_str(), v[0], v[1], v[2], v[2] - v[0], v[3], v[5],
            v[5] - v[0], v[6], v[1], v[4], v[7], v[8]);
        std::ostringstream o;
        o << csv_field(c.name) << "," << c.split;
        for (int k = 0; k < 9; ++k) o << "," << num(k == 8 ? v[k] / 100 : v[k], "%.6g");
        csv += o.str() + "\n";
    }
    std::printf(
        "%-*s %-5s | %6.2f %6.2f | %6.2f %+6.2f %+6.2f | %6.2f %+6.2f %+6.2f | %6.2f %6.2f %6.2f "
        "| %6.1f%%\n",
        name_w, "mean", split.c_str(), mean[0], mean[1], mean[2], mean[2] - mean[0], mean[3],
        mean[5], mean[5] - mean[0], mean[6], mean[1], mean[4], mean[7], mean[8]);
    std::printf(
        "least: each pixel from the view with the least true radius, where it is over 0.5 px "
        "sharper than the frame's own; near: the mean of the views within 0.5 px of that one; "
        "worst: the lowest frame's gain; tPSNR: in, least, near; sharper: pixels some other "
        "frame saw at least 1 px sharper\n");
    write_file_atomic(csv_path, csv);
    std::printf("CSV: %s\n", csv_path.c_str());
}

}  // namespace

int bench_corpus(int argc, char** argv) {
    Args a(argc, argv, 3, {"oracle-coc", "views"});
    a.check_known({"split", "preset", "minutes", "iters", "oracle-coc", "views", "csv", "seed",
                   "batch", "set"});
    if (a.positional().size() != 1)
        throw Error("usage: refocus bench corpus <dir> [--split dev|val|all] [--preset " +
                    preset_names() +
                    "] [--minutes M | --iters N] [--oracle-coc] [--csv FILE] | --views");
    const fs::path dir = a.positional()[0];
    const std::string split = a.get("split", "all");
    if (split != "dev" && split != "val" && split != "all")
        throw Error("--split must be dev, val or all (got '" + split + "')");
    if (a.has("views")) {
        print_views(dir, split, list_clips(dir, split, false),
                    a.get("csv", (dir / ("bench_" + split + "_views.csv")).string()));
        return 0;
    }
    const std::string preset = a.get("preset", "fast");
    find_preset(preset);  // an unknown preset fails before any fit
    // --iters alone fixes the steps (load-independent); neither: 5 minutes a clip.
    const double minutes = a.get_double("minutes", a.has("iters") ? 0.0 : 5.0);
    const bool oracle = a.has("oracle-coc");
    const FitSettings settings = bench_fit_settings(a, preset, minutes);
    const std::string csv_path =
        a.get("csv", (dir / ("bench_" + split + "_" + preset + ".csv")).string());
    const std::vector<CorpusClip> clips = list_clips(dir, split, oracle);
    const Run run{dir, split, preset,
                  (minutes > 0 ? num(minutes, "%g min a clip") : "") +
                      (minutes > 0 && a.has("iters") ? ", " : "") +
                      (a.has("iters") ? a.get("iters") + " steps a clip" : ""),
                  oracle};

    std::vector<ClipResult> results;
    const auto t0 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < clips.size(); ++i) {
        const CorpusClip& c = clips[i];
        const std::string label =
            "[" + std::to_string(i + 1) + "/" + std::to_string(clips.size()) + "] " + c.name;
        std::fprintf(stderr, "%s (%s, %d frames, %dx%d): fitting\n", label.c_str(), c.split.c_str(),
                     c.frames, c.width, c.height);
        results.push_back(fit_clip(c, settings, oracle, label));
        const EvalRow& r = results.back().row;
        std::fprintf(stderr, "%s: PSNR %.2f -> %.2f dB (%+.2f), %lld steps, %.0f s so far\n",
                     label.c_str(), r.in_psnr, r.psnr, r.psnr - r.in_psnr, (long long)r.step,
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        // Written after every clip: a run of hours that stops keeps what it measured.
        write_file_atomic(csv_path, csv_text(run, clips, results));
    }
    print_table(run, clips, results);
    std::printf("CSV: %s\n", csv_path.c_str());
    return 0;
}

}  // namespace refocus
