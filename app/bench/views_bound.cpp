#include "bench/views_bound.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "io/clip.h"
#include "io/image_file.h"
#include "metrics/metrics.h"
#include "util/error.h"
#include "util/fs.h"
#include "util/json_file.h"

namespace refocus {

namespace {

using Mat4 = std::array<double, 16>;  // row-major

// The inverse of a rigid camera-to-world matrix [R t; 0 1]: [Rᵀ −Rᵀt; 0 1].
Mat4 invert_rigid(const Mat4& a) {
    Mat4 r{};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r[i * 4 + j] = a[j * 4 + i];
    for (int i = 0; i < 3; ++i)
        r[i * 4 + 3] = -(r[i * 4] * a[3] + r[i * 4 + 1] * a[7] + r[i * 4 + 2] * a[11]);
    r[15] = 1;
    return r;
}

void apply(const Mat4& m, const double p[3], double q[3]) {
    for (int i = 0; i < 3; ++i)
        q[i] = m[i * 4] * p[0] + m[i * 4 + 1] * p[1] + m[i * 4 + 2] * p[2] + m[i * 4 + 3];
}

double bilinear(const Image& im, double x, double y, int c) {
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const double fx = x - x0, fy = y - y0;
    auto at = [&](int xx, int yy) {
        return double(im.at(std::clamp(xx, 0, im.width - 1), std::clamp(yy, 0, im.height - 1), c));
    };
    return (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x0 + 1, y0)) +
           fy * ((1 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1));
}

// Every frame of a pass; `frames` > 0: at least that many, the first `frames` kept.
std::vector<Image> read_pass(const std::filesystem::path& dir, const char* pass, const char* ext,
                             int frames) {
    const std::string pattern = (dir / (std::string(pass) + "_%04d." + ext)).string();
    char first[64];
    std::snprintf(first, sizeof first, "%s_0000.%s", pass, ext);
    if (!std::filesystem::exists(dir / first))
        throw Error(file_error((dir / first).string(), "missing (bench corpus --views)"));
    std::vector<Image> v = read_all_frames(pattern);
    if (static_cast<int>(v.size()) < frames)
        throw Error(file_error(
            pattern, std::to_string(v.size()) + " frames, the clip has " + std::to_string(frames)));
    if (frames > 0) v.resize(frames);
    return v;
}

}  // namespace

ViewsBound sharpest_view_bound(const std::filesystem::path& dir) {
    const std::string json_path = (dir / "clip.json").string();
    const nlohmann::json j = read_json_file(json_path);
    if (!j.contains("camera_world") || !j.contains("lens") || !j["lens"].contains("focal_px"))
        throw Error(file_error(json_path, "no camera_world or lens.focal_px (a rendered clip's)"));
    const std::vector<Image> input = read_pass(dir, "input", "png", 0);
    const int T = static_cast<int>(input.size()), W = input[0].width, H = input[0].height;
    const std::vector<Image> gt = read_pass(dir, "sharp", "png", T);
    const std::vector<Image> coc = read_pass(dir, "coc", "exr", T);
    const std::vector<Image> depth = read_pass(dir, "depth", "exr", T);
    if (!j["camera_world"].is_array() || static_cast<int>(j["camera_world"].size()) < T)
        throw Error(file_error(json_path, "camera_world has fewer matrices than frames"));
    std::vector<Image> alpha;
    for (int t = 0; t < T; ++t) {
        char name[32];
        std::snprintf(name, sizeof name, "alpha_%04d.png", t);
        if (std::filesystem::exists(dir / name))
            alpha.push_back(read_image_file((dir / name).string(), false).image);
    }
    const bool has_alpha = static_cast<int>(alpha.size()) == T;
    const double f = j["lens"]["focal_px"].get<double>();
    std::vector<Mat4> cam(T), world_to_cam(T);
    for (int t = 0; t < T; ++t) {
        for (int k = 0; k < 16; ++k) cam[t][k] = j["camera_world"][t][k].get<double>();
        world_to_cam[t] = invert_rigid(cam[t]);
    }

    struct View {
        double radius, x, y;
        int s;
    };
    ViewsBound b;
    std::vector<Image> least(T, Image(W, H, 3)), near(T, Image(W, H, 3));
    long sharper = 0;
    std::vector<View> views;
    for (int t = 0; t < T; ++t) {
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) {
                // Blender's camera looks down its local −Z with +Y up; the depth pass is z along
                // the optical axis (tools/corpus/README.md, The lens, checked).
                const double z = depth[t].at(x, y, 0);
                const double pc[3] = {(x + 0.5 - W / 2.0) / f * z, -(y + 0.5 - H / 2.0) / f * z,
                                      -z};
                double pw[3];
                apply(cam[t], pc, pw);
                const bool subject = has_alpha && alpha[t].at(x, y, 0) >= 0.5f;
                views.assign(1, {coc[t].at(x, y, 0), double(x), double(y), t});
                for (int s = 0; s < T && !subject; ++s) {
                    if (s == t) continue;
                    double q[3];
                    apply(world_to_cam[s], pw, q);
                    const double zs = -q[2];
                    if (!(zs > 1e-6)) continue;
                    const double u = q[0] / zs * f + W / 2.0 - 0.5;
                    const double v = -q[1] / zs * f + H / 2.0 - 0.5;
                    const double e = 1e-6;  // a view on the border is inside
                    if (u < -e || v < -e || u > W - 1 + e || v > H - 1 + e) continue;
                    const int ui = static_cast<int>(std::lround(u)),
                              vi = static_cast<int>(std::lround(v));
                    if (std::abs(depth[s].at(ui, vi, 0) - zs) > 0.03 * zs) continue;  // hidden
                    if (has_alpha && alpha[s].at(ui, vi, 0) >= 0.5f) continue;
                    views.push_back({coc[s].at(ui, vi, 0), u, v, s});
                }
                // Another view replaces the frame's own only where it is sharper by more than
                // the 0.5 px that resampling it into frame t can cost.
                const View* best = &views[0];
                for (const View& w : views)
                    if (w.radius < std::min(best->radius, views[0].radius - 0.5)) best = &w;
                if (best->radius < views[0].radius - 1.0) ++sharper;
                double sum[3] = {0, 0, 0};
                int n = 0;
                for (const View& w : views) {
                    if (w.radius > best->radius + 0.5 || (best == &views[0] && &w != best))
                        continue;
                    for (int c = 0; c < 3; ++c) sum[c] += bilinear(input[w.s], w.x, w.y, c);
                    ++n;
                }
                for (int c = 0; c < 3; ++c) {
                    least[t].at(x, y, c) =
                        static_cast<float>(bilinear(input[best->s], best->x, best->y, c));
                    near[t].at(x, y, c) = static_cast<float>(sum[c] / n);
                }
            }
        const double in = psnr(input[t], gt[t]), l = psnr(least[t], gt[t]),
                     m = psnr(near[t], gt[t]);
        b.in_psnr += in / T, b.least_psnr += l / T, b.near_psnr += m / T;
        b.least_worst = t == 0 ? l - in : std::min(b.least_worst, l - in);
        b.near_worst = t == 0 ? m - in : std::min(b.near_worst, m - in);
    }
    b.in_tpsnr = tpsnr(input, gt);
    b.least_tpsnr = tpsnr(least, gt);
    b.near_tpsnr = tpsnr(near, gt);
    b.sharper_share = double(sharper) / (double(T) * W * H);
    return b;
}

}  // namespace refocus
