#include "edit/uv_flow.h"

#include <algorithm>
#include <cmath>

namespace refocus {

namespace {

// A [H,W,2] map sampled bilinearly at (x, y); outside the frame, the border's value carried on
// by the border's slope (so Newton's steps keep their direction there).
struct UvMap {
    const float* p;
    int w, h;
    void at(double x, double y, double out[2]) const {
        const double cx = std::clamp(x, 0.0, w - 1.0), cy = std::clamp(y, 0.0, h - 1.0);
        bilinear(cx, cy, out);
        if (cx != x || cy != y) {
            double j[4];
            jacobian(cx, cy, j);
            out[0] += j[0] * (x - cx) + j[1] * (y - cy);
            out[1] += j[2] * (x - cx) + j[3] * (y - cy);
        }
    }
    void bilinear(double x, double y, double out[2]) const {
        const int x0 = std::min(int(x), w - 2 < 0 ? 0 : w - 2),
                  y0 = std::min(int(y), h - 2 < 0 ? 0 : h - 2);
        const int x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
        const double fx = x - x0, fy = y - y0;
        for (int c = 0; c < 2; ++c) {
            const double v00 = p[(size_t(y0) * w + x0) * 2 + c],
                         v01 = p[(size_t(y0) * w + x1) * 2 + c];
            const double v10 = p[(size_t(y1) * w + x0) * 2 + c],
                         v11 = p[(size_t(y1) * w + x1) * 2 + c];
            out[c] = (v00 * (1 - fx) + v01 * fx) * (1 - fy) + (v10 * (1 - fx) + v11 * fx) * fy;
        }
    }
    // d(u, v) / d(x, y) by central differences of one pixel, inside the frame: [ux uy; vx vy].
    void jacobian(double x, double y, double j[4]) const {
        const double xa = std::max(x - 1, 0.0), xb = std::min(x + 1, w - 1.0);
        const double ya = std::max(y - 1, 0.0), yb = std::min(y + 1, h - 1.0);
        double l[2], r[2], t[2], b[2];
        bilinear(xa, y, l), bilinear(xb, y, r), bilinear(x, ya, t), bilinear(x, yb, b);
        const double dx = std::max(xb - xa, 1e-9), dy = std::max(yb - ya, 1e-9);
        j[0] = (r[0] - l[0]) / dx, j[1] = (b[0] - t[0]) / dy;
        j[2] = (r[1] - l[1]) / dx, j[3] = (b[1] - t[1]) / dy;
    }
};

}  // namespace

Image uv_flow(const Layers& a, const Layers& b) {
    const torch::Tensor ab = a.uv_bg[0].contiguous(), bb = b.uv_bg[0].contiguous();
    const int h = int(ab.size(0)), w = int(ab.size(1));
    const bool two = a.uv_fg.defined() && b.uv_fg.defined() && a.alpha.defined();
    torch::Tensor af, bf, alpha;
    if (two) {
        af = a.uv_fg[0].contiguous(), bf = b.uv_fg[0].contiguous();
        alpha = a.alpha[0][0].contiguous();
    }
    const UvMap from_bg{ab.data_ptr<float>(), w, h}, to_bg{bb.data_ptr<float>(), w, h};
    const UvMap from_fg{two ? af.data_ptr<float>() : nullptr, w, h},
        to_fg{two ? bf.data_ptr<float>() : nullptr, w, h};
    Image out(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const bool fg = two && alpha.data_ptr<float>()[size_t(y) * w + x] > 0.5f;
            const UvMap& from = fg ? from_fg : from_bg;
            const UvMap& to = fg ? to_fg : to_bg;
            double u[2], s[2], j[4];
            from.bilinear(x, y, u);
            double qx = x, qy = y;
            for (int it = 0; it < 10; ++it) {
                to.at(qx, qy, s);
                to.jacobian(std::clamp(qx, 0.0, w - 1.0), std::clamp(qy, 0.0, h - 1.0), j);
                const double det = j[0] * j[3] - j[1] * j[2];
                if (!(std::abs(det) > 1e-12)) break;
                const double ex = u[0] - s[0], ey = u[1] - s[1];
                const double dx = (j[3] * ex - j[1] * ey) / det,
                             dy = (-j[2] * ex + j[0] * ey) / det;
                qx += std::clamp(dx, -w * 1.0, w * 1.0), qy += std::clamp(dy, -h * 1.0, h * 1.0);
                if (dx * dx + dy * dy < 1e-6) break;
            }
            out.at(x, y, 0) = float(qx - x);
            out.at(x, y, 1) = float(qy - y);
            out.at(x, y, 2) = 0.0f;
        }
    return out;
}

}  // namespace refocus
