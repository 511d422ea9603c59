// The preparation stage against ground truth made here: flow on a known translation, the
// consistency test on a known occlusion, homographies of a known pan/zoom, static detection,
// automatic masks of a known moving disc, the blur radius of known pillbox/Gaussian blurs, and
// bad user masks / damaged prep folders.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <random>

#include "io/image_file.h"
#include "prepare/prepare.h"
#include "prepare/proxy.h"
#include "project/project.h"
#include "synth/synth.h"
#include "prep_fixtures.h"
#include "test_util.h"
#include "util/error.h"

using namespace refocus;

using namespace refocus::test::prep;

TEST_CASE("flow: known translation is recovered to sub-pixel accuracy in the interior") {
    const int w = 128, h = 72;
    const cv::Mat tex = texture(220, 160, 7);
    const double dx = 2.6, dy = -1.4;  // content moves by (dx, dy) from frame 0 to frame 1
    const Image a = from_mat(warp(tex, translate(40, 40), w, h));
    const Image b = from_mat(warp(tex, translate(40 - dx, 40 - dy), w, h));
    const Image f = compute_flow(a, b);
    REQUIRE(f.channels == 2);
    double sum = 0, worst = 0;
    int count = 0;
    for (int y = 8; y < h - 8; ++y)
        for (int x = 8; x < w - 8; ++x) {
            const double e = std::hypot(f.at(x, y, 0) - dx, f.at(x, y, 1) - dy);
            sum += e, worst = std::max(worst, e), ++count;
        }
    const double epe = sum / count;
    MESSAGE("translation flow: mean end-point error " << epe << " px, max " << worst << " px");
    CHECK(epe < 0.5);
    CHECK(worst < 1.5);
}

TEST_CASE("flow: forward-backward consistency flags an occluded region") {
    const int w = 128, h = 72, sq = 28, x0 = 40, y0 = 22, step = 6;
    const cv::Mat bg = texture(w, h, 11), fg = texture(sq, sq, 12, 0.8);
    cv::Mat f0 = bg.clone(), f1 = bg.clone();
    fg.copyTo(f0(cv::Rect(x0, y0, sq, sq)));
    fg.copyTo(f1(cv::Rect(x0 + step, y0, sq, sq)));  // the square moves right by `step`
    const Image a = from_mat(f0), b = from_mat(f1);
    const Image fwd = compute_flow(a, b), bwd = compute_flow(b, a);
    const Image valid = flow_consistency(fwd, bwd);
    // Background just right of the square at t = 0 is covered at t = 1.
    int occ = 0, occ_flagged = 0, far = 0, far_flagged = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool flagged = valid.at(x, y, 0) < 0.5f;
            if (x >= x0 + sq && x < x0 + sq + step && y >= y0 + 2 && y < y0 + sq - 2)
                ++occ, occ_flagged += flagged;
            const bool near_square =
                x > x0 - 12 && x < x0 + sq + step + 12 && y > y0 - 12 && y < y0 + sq + 12;
            if (!near_square && x >= 4 && y >= 4 && x < w - 4 && y < h - 4)
                ++far, far_flagged += flagged;
        }
    const double occ_rate = double(occ_flagged) / occ, far_rate = double(far_flagged) / far;
    MESSAGE("occluded strip flagged " << occ_rate * 100 << "%, far background flagged "
                                      << far_rate * 100 << "%");
    CHECK(occ_rate > 0.6);
    CHECK(far_rate < 0.05);
}

namespace {
// A clip panning and zooming over a textured plane: frame t = plane(A_t p).
struct PanClip {
    std::vector<Image> frames;
    std::vector<cv::Matx33d> A;
};
PanClip pan_zoom_clip(int w, int h, int n) {
    cv::Mat plane = mondrian(300, 220, 3) * 0.6 + texture(300, 220, 4) * 0.4;
    PanClip c;
    for (int t = 0; t < n; ++t) {
        const cv::Matx33d A = translate(60 + 3.0 * t, 50 + 1.5 * t) *
                              scale_about(1.0 / (1.0 + 0.015 * t), w / 2.0, h / 2.0);
        c.A.push_back(A);
        c.frames.push_back(from_mat(warp(plane, A, w, h)));
    }
    return c;
}
}  // namespace

TEST_CASE("camera motion: homographies of a synthetic pan and zoom") {
    const int w = 128, h = 72, n = 6;
    PanClip clip = pan_zoom_clip(w, h, n);
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(clip.frames);
    const CameraMotion cm = estimate_camera_motion(clip.frames, &flow, MotionOptions{}, log);
    REQUIRE(int(cm.to_reference.size()) == n);
    double worst = 0;
    const double cx[4] = {0, w - 1.0, 0, w - 1.0}, cy[4] = {0, 0, h - 1.0, h - 1.0};
    for (int t = 0; t < n; ++t) {
        const cv::Matx33d truth = clip.A[0].inv() * clip.A[t];  // frame t → frame 0
        for (int i = 0; i < 4; ++i) {
            cv::Vec3d p = truth * cv::Vec3d(cx[i], cy[i], 1);
            double ex, ey;
            cm.to_reference[t].apply(cx[i], cy[i], ex, ey);
            worst = std::max(worst, std::hypot(ex - p[0] / p[2], ey - p[1] / p[2]));
        }
        if (t + 1 < n) CHECK(cm.pair_source[t] == "features");
    }
    MESSAGE("pan/zoom homographies: worst corner error "
            << worst << " px over " << n << " frames; max corner motion " << cm.max_displacement_px
            << " px");
    CHECK(worst < 1.0);
    CHECK_FALSE(cm.is_static);

    // Reference in the middle: frame t → frame 3.
    MotionOptions mid;
    mid.reference = 3;
    const CameraMotion cm3 = estimate_camera_motion(clip.frames, &flow, mid, log);
    double ex, ey;
    cm3.to_reference[3].apply(10, 10, ex, ey);
    CHECK(std::hypot(ex - 10, ey - 10) < 1e-9);
    const cv::Vec3d p = clip.A[3].inv() * clip.A[0] * cv::Vec3d(5, 7, 1);
    cm3.to_reference[0].apply(5, 7, ex, ey);
    CHECK(std::hypot(ex - p[0] / p[2], ey - p[1] / p[2]) < 1.0);
}

TEST_CASE("camera motion: a wide lens panning keeps its perspective (homography, not affine)") {
    // The camera turns about its vertical axis behind a 70-degree lens: frame t = plane(A_t p),
    // A_t = K R_y(θ_t) K⁻¹. Consecutive frames differ by a true homography whose perspective
    // terms an affine fit cannot hold; the chain must keep them.
    const int w = 160, h = 90, n = 6;
    const double f = 110, cx = w / 2.0, cy = h / 2.0;
    const cv::Matx33d K(f, 0, cx, 0, f, cy, 0, 0, 1);
    cv::Mat plane = mondrian(420, 260, 7) * 0.6 + texture(420, 260, 8) * 0.4;
    std::vector<Image> frames;
    std::vector<cv::Matx33d> A;
    for (int t = 0; t < n; ++t) {
        const double th = 0.035 * t;
        const cv::Matx33d R(std::cos(th), 0, std::sin(th), 0, 1, 0, -std::sin(th), 0, std::cos(th));
        A.push_back(translate(130, 85) * K * R * K.inv());
        frames.push_back(from_mat(warp(plane, A.back(), w, h)));
    }
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(frames);
    const CameraMotion cm = estimate_camera_motion(frames, &flow, MotionOptions{}, log);
    double worst = 0, worst_affine = 0;
    const double px[4] = {0, w - 1.0, 0, w - 1.0}, py[4] = {0, 0, h - 1.0, h - 1.0};
    for (int t = 1; t < n; ++t) {
        const cv::Matx33d truth = A[0].inv() * A[t];
        // What the best affine map would leave at the corners (the test's own yardstick).
        std::vector<cv::Point2f> a, b;
        for (int i = 0; i < 4; ++i) {
            const cv::Vec3d p = truth * cv::Vec3d(px[i], py[i], 1);
            a.emplace_back(px[i], py[i]);
            b.emplace_back(p[0] / p[2], p[1] / p[2]);
        }
        const cv::Mat af = cv::getAffineTransform(a.data(), b.data());
        const cv::Vec2d q = cv::Matx23d(af) * cv::Vec3d(px[3], py[3], 1);
        worst_affine = std::max(worst_affine, std::hypot(q[0] - b[3].x, q[1] - b[3].y));
        for (int i = 0; i < 4; ++i) {
            double ex, ey;
            cm.to_reference[t].apply(px[i], py[i], ex, ey);
            worst = std::max(worst, std::hypot(ex - b[i].x, ey - b[i].y));
        }
    }
    MESSAGE("perspective pan: worst corner error "
            << worst << " px (an affine chain misses a corner by " << worst_affine << " px)");
    CHECK(worst_affine > 3.0);
    CHECK(worst < 1.0);
}

TEST_CASE("camera motion: a featureless clip falls back to identity and says so") {
    std::vector<Image> flat(3, Image(64, 36, 3, 0.4f));
    PrepareLog log;
    const CameraMotion cm = estimate_camera_motion(flat, nullptr, MotionOptions{}, log);
    CHECK(cm.pair_source[0] == "identity");
    CHECK(cm.is_static);
    REQUIRE(!log.lines().empty());
    CHECK(log.lines()[0].find("identity") != std::string::npos);
}

TEST_CASE("decisions: a static clip is static, has no subject; a pan is not static") {
    const int w = 128, h = 72, n = 5;
    const cv::Mat tex = texture(w, h, 21) * 0.5 + mondrian(w, h, 22) * 0.5;
    std::vector<Image> frames;
    cv::RNG rng(5);
    for (int t = 0; t < n; ++t) {
        cv::Mat noise(h, w, CV_32FC3);
        rng.fill(noise, cv::RNG::NORMAL, 0.0, 0.004);  // sensor noise
        frames.push_back(from_mat(tex + noise));
    }
    PrepareOptions opts;
    opts.estimate_coc = false;
    PrepareLog log;
    const PrepareResult r = prepare_clip(frames, opts, log);
    MESSAGE("static clip: corners move up to " << r.motion.max_displacement_px << " px");
    CHECK(r.decisions.static_camera);
    CHECK_FALSE(r.decisions.has_subject);
    auto logged = [&](const PrepareResult& res, const std::string& s) {
        for (const auto& l : res.log)
            if (l.find(s) != std::string::npos) return true;
        return false;
    };
    CHECK(logged(r, "static camera: no learned background warp"));
    CHECK(logged(r, "no moving subject: one layer"));

    PrepareLog log2;
    const PrepareResult p = prepare_clip(pan_zoom_clip(w, h, 4).frames, opts, log2);
    CHECK_FALSE(p.decisions.static_camera);
    CHECK_FALSE(logged(p, "static camera"));
}

TEST_CASE("camera motion: a large subject walking toward a static camera leaves it static") {
    // A textured subject covering much of the frame grows and slides over a locked-off wall.
    // Its tracks reach the frame's outer ring, and the first estimate may follow them; with the
    // subject's masks left out the camera is the wall's: static.
    const int w = 160, h = 96, n = 8;
    const cv::Mat wall = texture(w, h, 51) * 0.5 + mondrian(w, h, 52) * 0.5;
    const cv::Mat body = texture(200, 200, 53, 0.9) * 0.7 + 0.2;
    std::vector<Image> frames, masks;
    for (int t = 0; t < n; ++t) {
        cv::Mat f = wall.clone();
        Image m(w, h, 1, 0.0f);
        const double s = 1.0 + 0.06 * t, cx = 74 + 2.0 * t, cy = 50;  // nearer every frame
        const double hw = 46 * s, hh = 36 * s;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                if (std::abs(x - cx) <= hw && std::abs(y - cy) <= hh) {
                    const int u = std::clamp(int(100 + (x - cx) / s), 0, 199),
                              v = std::clamp(int(100 + (y - cy) / s), 0, 199);
                    f.at<cv::Vec3f>(y, x) = body.at<cv::Vec3f>(v, u);
                    m.pixels[y * w + x] = 1.0f;
                }
        frames.push_back(from_mat(f));
        masks.push_back(std::move(m));
    }
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(frames);
    const CameraMotion all = estimate_camera_motion(frames, &flow, MotionOptions{}, log);
    const CameraMotion bg = estimate_camera_motion(frames, &flow, MotionOptions{}, log, &masks);
    MESSAGE("corners move up to " << all.max_displacement_px << " px with the subject's tracks, "
                                  << bg.max_displacement_px << " px without");
    CHECK(bg.is_static);
    CHECK(bg.max_displacement_px <= all.max_displacement_px + 1e-9);

    // The preparation does the same with its own masks: the first estimate's, then the
    // background's, and the decision follows the background.
    PrepareOptions opts;
    opts.estimate_coc = false;
    PrepareLog log2;
    const PrepareResult r = prepare_clip(frames, opts, log2);
    for (const auto& l : r.log)
        if (l.find("camera") != std::string::npos) MESSAGE(l);
    CHECK(r.decisions.static_camera);
}

TEST_CASE("masks: automatic mask of a moving disc over a panned texture") {
    const int w = 128, h = 72, n = 8;
    std::vector<Image> frames;
    std::vector<cv::Mat> truth;
    disc_clip(w, h, n, frames, truth);
    PrepareOptions opts;
    opts.estimate_coc = false;
    PrepareLog log;
    const PrepareResult r = prepare_clip(frames, opts, log);
    CHECK_FALSE(r.decisions.static_camera);
    CHECK(r.decisions.has_subject);
    double sum = 0, worst = 1;
    for (int t = 0; t < n; ++t) {
        int inter = 0, uni = 0;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const bool a = r.masks[t].at(x, y, 0) > 0.5f, b = truth[t].at<unsigned char>(y, x);
                inter += a && b, uni += a || b;
            }
        const double iou = uni ? double(inter) / uni : 1.0;
        sum += iou, worst = std::min(worst, iou);
    }
    MESSAGE("auto mask IoU against the true disc: mean " << sum / n << ", worst frame " << worst);
    CHECK(sum / n > 0.7);
    CHECK(worst > 0.5);
}

TEST_CASE("coc: calibrated conversion from the ratio estimator's sigma") {
    // The estimator's reading on ideal edges inverts back to the radius it was made from.
    for (double r : {0.0, 1.0, 2.5, 4.0, 7.0, 12.0}) {
        for (CocPsf psf : {CocPsf::Disk, CocPsf::Gaussian}) {
            const double s = sigma_of_coc(r, psf, 1.0);
            CHECK(coc_from_sigma(s, psf, 1.0) == doctest::Approx(r).epsilon(0.02).scale(1.0));
        }
    }
    // A pillbox reads σ ≈ r (half-ellipse LSF), a Gaussian of σ = r/2 reads ≈ r/2.
    CHECK(sigma_of_coc(8.0, CocPsf::Disk, 1.0) == doctest::Approx(8.0).epsilon(0.1));
    CHECK(sigma_of_coc(8.0, CocPsf::Gaussian, 1.0) == doctest::Approx(4.0).epsilon(0.1));
}

TEST_CASE("coc: radius of known pillbox and Gaussian blurs") {
    // Rectangles of 24-60 px: edges mostly farther apart than the blur. (On denser texture the
    // largest radii read low: neighbouring edges steepen the reblurred profile.)
    const int w = 128, h = 72;
    const cv::Mat sharp = mondrian(w, h, 41, 24, 60, 500);
    double worst = 0;
    for (double noise : {0.0, 0.005}) {
        for (CocPsf psf : {CocPsf::Disk, CocPsf::Gaussian}) {
            for (double r : {2.0, 4.0, 6.0}) {
                cv::Mat blurred;
                if (psf == CocPsf::Disk)
                    cv::filter2D(sharp, blurred, CV_32F, disk_kernel(r), cv::Point(-1, -1), 0,
                                 cv::BORDER_REFLECT);
                else
                    cv::GaussianBlur(sharp, blurred, cv::Size(0, 0), r / 2, r / 2,
                                     cv::BORDER_REFLECT);
                if (noise > 0) {
                    cv::Mat nz(blurred.size(), blurred.type());
                    cv::RNG rng(3);
                    rng.fill(nz, cv::RNG::NORMAL, 0.0, noise);
                    blurred += nz;
                }
                CocOptions o;
                o.psf = psf;
                const Image frame = from_mat(blurred);
                Image weight;
                const Image edges = estimate_coc_at_edges(frame, o, weight);
                std::vector<float> at_edges;
                for (size_t i = 0; i < edges.pixels.size(); ++i)
                    if (weight.pixels[i] > 0) at_edges.push_back(edges.pixels[i]);
                const Image dense = estimate_coc(frame, o);
                const double med_edges = median(at_edges), med = median(dense.pixels);
                MESSAGE(std::string(psf == CocPsf::Disk ? "pillbox" : "gaussian")
                        << " r=" << r << " noise=" << noise << ": median at " << at_edges.size()
                        << " edge px " << med_edges << ", dense median " << med);
                CHECK(std::abs(med - r) <= 0.2 * r);
                worst = std::max(worst, std::abs(med - r) / r);
            }
        }
    }
    MESSAGE("coc: worst relative error of the dense median " << worst * 100 << "%");
    // A sharp frame reads (almost) zero, and prepare calls it sharp.
    const Image dense = estimate_coc(from_mat(sharp), CocOptions{});
    const double med = median(dense.pixels);
    size_t below = 0;
    for (float v : dense.pixels) below += v < 0.5f;
    MESSAGE("sharp frame: dense median " << med << ", " << 100.0 * below / dense.size()
                                         << "% of pixels below 0.5 px");
    CHECK(med < 0.5);
    CHECK(double(below) / dense.size() >= 0.9);
    PrepareLog log;
    PrepareResult sharp_clip = prepare_clip({from_mat(sharp), from_mat(sharp)}, {}, log);
    CHECK(sharp_clip.decisions.all_sharp);
    CHECK(sharp_clip.log.back().find("frames already sharp") != std::string::npos);
    cv::Mat blurred;
    cv::GaussianBlur(sharp, blurred, cv::Size(0, 0), 1.5);
    PrepareLog log2;
    PrepareResult blurred_clip = prepare_clip({from_mat(blurred), from_mat(blurred)}, {}, log2);
    CHECK_FALSE(blurred_clip.decisions.all_sharp);
    CHECK(blurred_clip.decisions.frame_sharp[0] == 0);
}

TEST_CASE("coc: two blur levels in one frame are told apart, and temporal smoothing keeps them") {
    const int w = 128, h = 72;
    const cv::Mat sharp = mondrian(w, h, 43, 24, 60, 500);
    cv::Mat a, b;
    cv::filter2D(sharp, a, CV_32F, disk_kernel(1.5), cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
    cv::filter2D(sharp, b, CV_32F, disk_kernel(5.0), cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
    cv::Mat mixed = a.clone();
    b(cv::Rect(w / 2, 0, w / 2, h)).copyTo(mixed(cv::Rect(w / 2, 0, w / 2, h)));
    std::vector<Image> frames(3, from_mat(mixed));
    std::vector<Image> coc;
    for (const auto& f : frames) coc.push_back(estimate_coc(f));
    const ClipFlow flow = compute_clip_flow(frames);
    const std::vector<Image> smooth = smooth_coc_temporally(coc, flow);
    const std::vector<Image>* both[2] = {&coc, &smooth};
    for (const std::vector<Image>* maps : both) {
        std::vector<float> left, right;
        const Image& c = (*maps)[1];
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                if (x < w / 2 - 8) left.push_back(c.at(x, y, 0));
                if (x >= w / 2 + 8) right.push_back(c.at(x, y, 0));
            }
        const double ml = median(left), mr = median(right);
        MESSAGE(std::string(maps == &coc ? "per frame" : "smoothed")
                << ": left (r=1.5) median " << ml << ", right (r=5) median " << mr);
        CHECK(std::abs(ml - 1.5) <= 0.3 * 1.5);
        CHECK(std::abs(mr - 5.0) <= 0.3 * 5.0);
    }
}

TEST_CASE("masks: bad user masks give errors naming the file") {
    const fs::path dir = test::scratch_dir("prepare_bad_masks");
    const int w = 32, h = 18, n = 4;
    Image m(w, h, 1, 1.0f);
    auto write = [&](int i, const Image& img) {
        char name[32];
        std::snprintf(name, sizeof name, "mask_%04d.png", i);
        write_image_file((dir / name).string(), img, PixelFormat::Png8, false);
        return (dir / name).string();
    };
    for (int i = 0; i < n; ++i) write(i, m);
    const std::string pattern = (dir / "mask_%04d.png").string();
    CHECK(load_masks(pattern, n, w, h).size() == size_t(n));
    CHECK(load_masks(dir.string(), n, w, h).size() == size_t(n));
    CHECK(load_masks(pattern, n, w, h)[2].at(3, 3, 0) == doctest::Approx(1.0f));

    // Wrong count: one too many / one too few.
    std::string e = error_of([&] { load_masks(pattern, n - 1, w, h); });
    CHECK(e.find("mask_0003.png") != std::string::npos);
    CHECK(e.find("too many") != std::string::npos);
    e = error_of([&] { load_masks(pattern, n + 1, w, h); });
    CHECK(e.find("mask_0004.png") != std::string::npos);
    CHECK(e.find("missing") != std::string::npos);
    e = error_of([&] { load_masks(dir.string(), n + 1, w, h); });
    CHECK(e.find(dir.string()) != std::string::npos);
    CHECK(e.find("holds 4") != std::string::npos);

    // Wrong size.
    const std::string bad = write(2, Image(w / 2, h / 2, 1, 1.0f));
    e = error_of([&] { load_masks(pattern, n, w, h); });
    CHECK(e.find(bad) != std::string::npos);
    CHECK(e.find("16x9") != std::string::npos);
    write(2, m);

    // Missing in the middle.
    fs::remove(dir / "mask_0001.png");
    e = error_of([&] { load_masks(pattern, n, w, h); });
    CHECK(e.find("mask_0001.png") != std::string::npos);
    CHECK(e.find("missing") != std::string::npos);

    // Nothing there at all.
    e = error_of([&] { load_masks((dir / "nope_%04d.png").string(), n, w, h); });
    CHECK(e.find("nope_0000.png") != std::string::npos);
}

TEST_CASE("prep folder: save, load, and damaged files named") {
    const fs::path root = test::scratch_dir("prepare_project");
    const int w = 64, h = 36, n = 4;
    std::vector<Image> frames;
    std::vector<cv::Mat> truth;
    disc_clip(w, h, n, frames, truth);
    test::write_png_sequence(root / "clip", frames, true);
    const Project project = create_project((root / "clip").string(), root / "proj", {});
    std::vector<Image> cached;
    for (int t = 0; t < n; ++t) cached.push_back(project.read_frame(t));
    PrepareLog log;
    const PrepareResult r = prepare_clip(cached, PrepareOptions{}, log);
    save_prepare(project, r);
    CHECK(has_prepare(project));

    const PrepareResult l = load_prepare(project);
    REQUIRE(l.frames == n);
    REQUIRE(l.flow.fwd.size() == size_t(n - 1));
    REQUIRE(l.coc.size() == size_t(n));
    double flow_err = 0, coc_err = 0, mask_err = 0, valid_err = 0, h_err = 0;
    for (int t = 0; t + 1 < n; ++t) {
        flow_err = std::max(flow_err, test::max_abs_diff(l.flow.fwd[t], r.flow.fwd[t]));
        flow_err = std::max(flow_err, test::max_abs_diff(l.flow.bwd[t], r.flow.bwd[t]));
        valid_err =
            std::max(valid_err, test::max_abs_diff(l.flow.bwd_valid[t], r.flow.bwd_valid[t]));
    }
    for (int t = 0; t < n; ++t) {
        coc_err = std::max(coc_err, test::max_abs_diff(l.coc[t], r.coc[t]));
        mask_err = std::max(mask_err, test::max_abs_diff(l.masks[t], r.masks[t]));
        for (int i = 0; i < 9; ++i)
            h_err = std::max(
                h_err, std::abs(l.motion.to_reference[t].m[i] - r.motion.to_reference[t].m[i]));
    }
    CHECK(flow_err == 0.0);
    CHECK(valid_err == 0.0);
    CHECK(coc_err == 0.0);
    CHECK(mask_err < 1.0 / 255);
    CHECK(h_err == 0.0);
    CHECK(l.decisions.static_camera == r.decisions.static_camera);
    CHECK(l.decisions.has_subject == r.decisions.has_subject);
    CHECK(l.log == r.log);

    const fs::path prep = prepare_dir(project);
    // A radius map gone.
    fs::rename(prep / "coc_0002.exr", prep / "coc_0002.bak");
    std::string e = error_of([&] { load_prepare(project); });
    CHECK(e.find("coc_0002.exr") != std::string::npos);
    fs::rename(prep / "coc_0002.bak", prep / "coc_0002.exr");
    // A mask of the wrong size.
    write_image_file((prep / "mask_0001.png").string(), Image(w, h / 2, 1, 0.0f), PixelFormat::Png8,
                     false);
    e = error_of([&] { load_prepare(project); });
    CHECK(e.find("mask_0001.png") != std::string::npos);
    CHECK(e.find("differs") != std::string::npos);
    save_prepare(project, r);
    CHECK_NOTHROW(load_prepare(project));
    // prepare.json for another clip length.
    std::string text = read_text_file(prep / "prepare.json");
    const std::string from = "\"frames\": " + std::to_string(n);
    REQUIRE(text.find(from) != std::string::npos);
    text.replace(text.find(from), from.size(), "\"frames\": 7");
    write_file_atomic(prep / "prepare.json", text);
    e = error_of([&] { load_prepare(project); });
    CHECK(e.find("prepare.json") != std::string::npos);
    CHECK(e.find("7 frames") != std::string::npos);
    // Not JSON at all.
    write_file_atomic(prep / "prepare.json", "{ nope");
    e = error_of([&] { load_prepare(project); });
    CHECK(e.find("prepare.json") != std::string::npos);
}

namespace {
// The synth hunt clip at 240x135x16: focus hunts around a subject that walks ~0.7 px a frame
// across a wall that moves ~0.1 px a frame. Its frames and true alpha.
SynthOptions hunt_options() {
    SynthOptions so;
    so.scene = "hunt";
    so.width = 240;
    so.height = 135;
    so.frames = 16;
    return so;
}
void render_all(const SynthClip& clip, int n, std::vector<Image>& frames,
                std::vector<Image>* alpha = nullptr) {
    for (int t = 0; t < n; ++t) {
        SynthFrame f = clip.render(t);
        frames.push_back(std::move(f.input));
        if (alpha) alpha->push_back(std::move(f.alpha));
    }
}
}  // namespace

TEST_CASE("camera motion: the wall's motion, not a sharp subject's, when the wall is blurred") {
    // When focus is on the hunt clip's subject its corners track cleanly and the wall's
    // (blurred, the blur changing every frame) do not. The homographies must follow the wall:
    // chained, their error at the frame centre is compared with the truth.
    const SynthOptions so = hunt_options();
    SynthClip clip(so);
    std::vector<Image> frames;
    render_all(clip, so.frames, frames);
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(frames);
    const CameraMotion cm = estimate_camera_motion(frames, &flow, MotionOptions{}, log);
    const double W = so.width, H = so.height, cx = W / 2, cy = H / 2;
    const double top = clip.bg_invdepth_top(), bot = clip.bg_invdepth_bottom();
    const auto s0 = clip.state(0);
    double worst = 0;
    for (int t = 1; t < so.frames; ++t) {
        const auto st = clip.state(t);
        // A wall point seen at (cx, cy) in frame t sits in frame 0 at (x0, y0) (synth.cpp).
        const double d = top + (bot - top) * (cy - st.shake_y + 0.5) / H;
        const double x0 = cx - (st.pan - s0.pan) * d - (st.shake_x - s0.shake_x);
        const double y0 = cy - st.shake_y + s0.shake_y;
        double ex, ey;
        cm.to_reference[t].apply(cx, cy, ex, ey);
        worst = std::max(worst, std::hypot(ex - x0, ey - y0));
    }
    // Whole-frame homography consensus: 8.0 px; the outer ring's: 1.6 px; affine, weak pairs
    // interpolated: 0.8 px.
    MESSAGE("hunt homographies: worst centre error " << worst << " px over " << so.frames
                                                     << " frames");
    CHECK(worst < 1.5);
}

TEST_CASE("masks: a slow subject under hunting focus is found (synth hunt)") {
    // The subject walks ~0.7 px a frame against the wall while focus swings the wall's blur by
    // several px from frame to frame. Adjacent frames' flow residual cannot tell the two apart
    // (its masks, at 320x180: mean IoU 0.14); the long baselines can (0.77).
    const SynthOptions so = hunt_options();
    SynthClip clip(so);
    std::vector<Image> frames, alpha;
    render_all(clip, so.frames, frames, &alpha);
    PrepareLog log;
    const ClipFlow flow = compute_clip_flow(frames);
    const CameraMotion cm = estimate_camera_motion(frames, &flow, MotionOptions{}, log);
    const auto masks = automatic_masks(frames, &flow, cm);
    double sum = 0, worst = 1;
    for (int t = 0; t < so.frames; ++t) {
        int inter = 0, uni = 0;
        for (int y = 0; y < so.height; ++y)
            for (int x = 0; x < so.width; ++x) {
                const bool a = masks[t].at(x, y, 0) > 0.5f, b = alpha[t].at(x, y, 0) >= 0.5f;
                inter += a && b, uni += a || b;
            }
        const double iou = uni ? double(inter) / uni : 1.0;
        sum += iou, worst = std::min(worst, iou);
    }
    MESSAGE("hunt auto mask IoU against the true alpha: mean " << sum / so.frames
                                                               << ", worst frame " << worst);
    CHECK(sum / so.frames > 0.6);
    CHECK(worst > 0.3);
}

TEST_CASE("proxy: sizes, and homographies and flow carried from a proxy to the full size") {
    const ProxySize same = proxy_size(320, 180, 640);
    CHECK_FALSE(same.active());
    CHECK((same.width == 320 && same.height == 180));
    CHECK_FALSE(proxy_size(1920, 1080, 0).active());
    const ProxySize hd = proxy_size(1920, 1080, 640);
    CHECK((hd.width == 640 && hd.height == 360 && hd.sx == 3 && hd.sy == 3));
    const ProxySize odd = proxy_size(1000, 333, 300);  // 99.9 rounds to 100
    CHECK((odd.width == 300 && odd.height == 100));
    CHECK_THROWS_AS(proxy_size(0, 10, 640), Error);
    CHECK_THROWS_AS(proxy_size(10, 10, -1), Error);

    // S·H_p·S⁻¹ carries a proxy point's image to the full-size point's image.
    Homography hp;
    hp.m = {1.01, 0.02, 3.5, -0.015, 0.99, -2.25, 1e-4, -2e-4, 1};
    const double sx = 3, sy = 2.5;
    const Homography hf = scale_homography(hp, sx, sy);
    double worst = 0;
    for (double xp : {0.0, 17.5, 99.0})
        for (double yp : {0.0, 40.25, 59.0}) {
            double qx, qy, fx, fy;
            hp.apply(xp, yp, qx, qy);
            hf.apply(sx * xp + (sx - 1) / 2, sy * yp + (sy - 1) / 2, fx, fy);
            worst = std::max(
                worst, std::hypot(fx - (sx * qx + (sx - 1) / 2), fy - (sy * qy + (sy - 1) / 2)));
        }
    CHECK(worst < 1e-9);

    // A pan and zoom prepared on its half-size proxy: the scaled-up homographies against the
    // truth at full size, and the flow's vectors in full-size px.
    const int w = 256, h = 144, n = 5;
    PanClip clip = pan_zoom_clip(w, h, n);
    const ProxySize px = proxy_size(w, h, 128);
    std::vector<Image> small;
    for (const Image& f : clip.frames) small.push_back(resize_image(f, px.width, px.height));
    PrepareOptions opts;
    opts.estimate_coc = false;
    PrepareLog log;
    const PrepareResult pr = prepare_clip(small, opts, log);
    const PrepareResult full = scale_prepare(pr, w, h);
    REQUIRE((full.width == w && full.height == h && full.flow.fwd[0].width == w));
    double corner = 0;
    const double cx[4] = {0, w - 1.0, 0, w - 1.0}, cy[4] = {0, 0, h - 1.0, h - 1.0};
    for (int t = 0; t < n; ++t) {
        const cv::Matx33d truth = clip.A[0].inv() * clip.A[t];
        for (int i = 0; i < 4; ++i) {
            const cv::Vec3d q = truth * cv::Vec3d(cx[i], cy[i], 1);
            double ex, ey;
            full.motion.to_reference[t].apply(cx[i], cy[i], ex, ey);
            corner = std::max(corner, std::hypot(ex - q[0] / q[2], ey - q[1] / q[2]));
        }
    }
    // Flow 0 → 1 at the frame's centre region, against frame 1's truth.
    std::vector<float> err;
    const cv::Matx33d to1 = clip.A[1].inv() * clip.A[0];
    for (int y = h / 4; y < 3 * h / 4; y += 4)
        for (int x = w / 4; x < 3 * w / 4; x += 4) {
            const cv::Vec3d q = to1 * cv::Vec3d(x, y, 1);
            err.push_back(float(std::hypot(x + full.flow.fwd[0].at(x, y, 0) - q[0] / q[2],
                                           y + full.flow.fwd[0].at(x, y, 1) - q[1] / q[2])));
        }
    MESSAGE("pan/zoom 256x144 on a 128x72 proxy: worst corner error "
            << corner << " px, median flow error " << median(err) << " px at full size");
    CHECK(corner < 2.0);
    CHECK(median(err) < 0.5);
}
