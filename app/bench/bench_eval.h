#pragma once
// What `bench fit` and `bench corpus` share: the fit's settings from the command line, and the
// scoring of a fit's sharp output against a clip's ground truth.
#include <string>
#include <vector>

#include "args.h"
#include "io/image.h"
#include "session/fit_session.h"

namespace refocus {

// The figures of one evaluation (mean over the frames done; sRGB 8-bit, dB).
struct EvalRow {
    double minutes = 0;
    int64_t step = 0;
    double psnr = 0, ssim = 0, tpsnr = 0, reblur_psnr = 0;
    int frames_done = 0;                            // frames the figures cover
    double in_psnr = 0, in_ssim = 0, in_tpsnr = 0;  // the input's on the same frames
};

// The frames an evaluation scored: the sharp output as exported, the truth and the input, on
// the frames done (`index` holds their frame numbers).
struct EvalFrames {
    std::vector<Image> sharp, gt, input;
    std::vector<Image> model;  // the model's plate alone: no output rule, no low-frequency lock
    std::vector<int> index;
};

// The oracle blend (the yardstick of the output rules): per pixel the better of the input and
// the model's plate, chosen with the truth (squared errors in sRGB levels box-averaged over 3x3
// px, the 0/1 choice box-averaged over 3x3 px), blended in sRGB. Its PSNR is the most any rule
// that mixes the two can give this model. Linear frames in; the blend's PSNR (dB) out.
double oracle_blend_psnr(const Image& model, const Image& input, const Image& gt);

// Figures over the frames the fit has produced. `perframe` deconvolves one frame per step and
// may run out of time before the last: the frames not reached still hold the input, so they
// are left out (and the input's figures are recomputed on the same frames for the comparison);
// tPSNR then covers the leading run of consecutive frames done (0 with fewer than 2). The sharp
// frames are those `refocus export` writes: the engine's fallback applied.
EvalRow evaluate(FitEngine& engine, const std::vector<Image>& gt, const std::vector<Image>& input,
                 EvalFrames* keep = nullptr);

// The fit's settings from the options both benches take: --set name=value (repeated), --iters,
// --seed, --batch; `preset` and `minutes` as the command resolved them.
FitSettings bench_fit_settings(const Args& a, const std::string& preset, double minutes);

}  // namespace refocus
