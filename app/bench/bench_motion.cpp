// refocus bench motion: the camera-motion estimate (prepare's homographies) against a synth
// clip's true wall motion. The wall is the plane whose inverse depth runs from `invdepth_top` to
// `invdepth_bottom` down the frame; a wall point seen at (x, y) in frame t sits in frame 0 at
//   x0 = x − (pan_t − pan_0)·d − (shake_x,t − shake_x,0),   y0 = y − shake_y,t + shake_y,0,
//   d = top + (bottom − top)·(y − shake_y,t + 0.5)/H          (engine/synth/synth.cpp)
// Prints each pair's error and the chained error against frame 0, at a 5x5 grid of points.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "args.h"
#include "commands.h"
#include "io/clip.h"
#include "io/image_file.h"
#include "prepare/flow.h"
#include "prepare/masks.h"
#include "prepare/motion.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

int bench_motion(int argc, char** argv) {
    Args a(argc, argv, 3, {"pairs"});
    a.check_known({"clip", "pairs", "dump"});
    if (!a.has("clip"))
        throw Error("usage: refocus bench motion --clip <synth-dir> [--pairs] [--dump <dir>]");
    const fs::path clip = a.get("clip");
    if (!fs::exists(clip / "clip.json"))
        throw Error(file_error(clip.string(), "not a refocus synth clip (no clip.json)"));
    const auto j = nlohmann::json::parse(read_text_file(clip / "clip.json"));
    std::vector<Image> frames = read_all_frames((clip / "input_%04d.png").string());
    const int n = static_cast<int>(frames.size());
    if (n < 2) throw Error(file_error(clip.string(), "needs at least 2 frames"));
    const double W = frames[0].width, H = frames[0].height;
    const double top = j.at("background").at("invdepth_top"),
                 bot = j.at("background").at("invdepth_bottom");
    const auto& pan = j.at("camera").at("pan");
    const auto& shake = j.at("camera").at("shake_px");
    // True map frame t → frame 0 of a wall point.
    auto truth = [&](int t, double x, double y, double& x0, double& y0) {
        const double sx = double(shake[t][0]) - double(shake[0][0]);
        const double syt = shake[t][1], sy0 = shake[0][1];
        const double d = top + (bot - top) * (y - syt + 0.5) / H;
        x0 = x - (double(pan[t]) - double(pan[0])) * d - sx;
        y0 = y - syt + sy0;
    };
    auto truth_inv = [&](int t, double x0, double y0, double& x, double& y) {  // frame 0 → frame t
        const double sx = double(shake[t][0]) - double(shake[0][0]);
        const double syt = shake[t][1], sy0 = shake[0][1];
        y = y0 + syt - sy0;
        const double d = top + (bot - top) * (y - syt + 0.5) / H;
        x = x0 + (double(pan[t]) - double(pan[0])) * d + sx;
    };
    const auto t0 = std::chrono::steady_clock::now();
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(frames);
    const auto t1 = std::chrono::steady_clock::now();
    MotionOptions mo;
    mo.static_max_px = 2.0;  // as `refocus fit` decides (engine/fit/fit_setup.cpp)
    const CameraMotion cm = estimate_camera_motion(frames, &flow, mo, log);
    const auto t2 = std::chrono::steady_clock::now();
    auto grid_error = [&](int t, const Homography& est_to0) {  // worst over the 5x5 grid
        double worst = 0;
        for (int i = 0; i < 5; ++i)
            for (int k = 0; k < 5; ++k) {
                const double x = (W - 1) * (0.1 + 0.2 * i), y = (H - 1) * (0.1 + 0.2 * k);
                double ex, ey, tx, ty;
                est_to0.apply(x, y, ex, ey);
                truth(t, x, y, tx, ty);
                worst = std::max(worst, std::hypot(ex - tx, ey - ty));
            }
        return worst;
    };
    double pair_sum = 0, pair_max = 0, chain_max = 0;
    for (int t = 1; t < n; ++t) {
        const double chain = grid_error(t, cm.to_reference[t]);
        double pe = 0;  // the pair's own error (t → t−1), worst over the grid
        for (int i = 0; i < 5; ++i)
            for (int k = 0; k < 5; ++k) {
                const double x = (W - 1) * (0.1 + 0.2 * i), y = (H - 1) * (0.1 + 0.2 * k);
                double x0, y0, tx, ty, ex, ey;
                truth(t, x, y, x0, y0);
                truth_inv(t - 1, x0, y0, tx, ty);
                cm.pair[t - 1].apply(x, y, ex, ey);
                pe = std::max(pe, std::hypot(ex - tx, ey - ty));
            }
        pair_sum += pe;
        pair_max = std::max(pair_max, pe);
        chain_max = std::max(chain_max, chain);
        if (a.has("pairs"))
            std::printf(
                "frame %3d: source %-8s inliers %4d  pair error %.2f px  chained error %.2f px\n",
                t, cm.pair_source[t - 1].c_str(), cm.pair_inliers[t - 1], pe, chain);
    }
    // Automatic masks (prepare/masks.h) against the clip's true alpha: intersection over union.
    const auto m0 = std::chrono::steady_clock::now();
    std::vector<Image> residuals;
    const auto masks = automatic_masks(frames, &flow, cm, MaskOptions{}, &residuals);
    const double mask_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - m0).count();
    if (a.has("dump")) {  // residuals and masks as PNG, to look at
        const fs::path dir = a.get("dump");
        fs::create_directories(dir);
        for (int t = 0; t < n; ++t) {
            Image view = residuals[t];  // 0..4 px → black..white
            for (float& v : view.pixels) v = std::clamp(v / 4.0f, 0.0f, 1.0f);
            write_image_file((dir / format_pattern("residual_%04d.png", t)).string(), view,
                             PixelFormat::Png8, false);
            write_image_file((dir / format_pattern("mask_%04d.png", t)).string(), masks[t],
                             PixelFormat::Png8, false);
        }
    }
    double iou_sum = 0, cover = 0;
    for (int t = 0; t < n; ++t) {
        const Image alpha =
            read_image_file((clip / format_pattern("alpha_%04d.png", t)).string(), false).image;
        double inter = 0, uni = 0;
        for (int y = 0; y < alpha.height; ++y)
            for (int x = 0; x < alpha.width; ++x) {
                const bool g = alpha.at(x, y, 0) >= 0.5f, m = masks[t].at(x, y, 0) >= 0.5f;
                inter += g && m;
                uni += g || m;
                cover += m;
            }
        const double iou = uni > 0 ? inter / uni : 1.0;
        iou_sum += iou;
        if (a.has("pairs")) std::printf("frame %3d: automatic mask IoU %.2f\n", t, iou);
    }
    std::printf(
        "%s: automatic masks (%.1f s): mean IoU against the true alpha %.2f, cover %.1f%% of the "
        "frame\n",
        clip.filename().string().c_str(), mask_s, iou_sum / n, 100.0 * cover / (double(n) * W * H));
    std::printf(
        "%s: %d frames, flow %.1f s, homographies %.2f s; pair error mean %.2f max "
        "%.2f px; chained error to frame 0 max %.2f px; corners move up to %.2f px (%s)\n",
        clip.filename().string().c_str(), n, std::chrono::duration<double>(t1 - t0).count(),
        std::chrono::duration<double>(t2 - t1).count(), pair_sum / (n - 1), pair_max, chain_max,
        cm.max_displacement_px, cm.is_static ? "static" : "moving");
    return 0;
}

}  // namespace refocus
