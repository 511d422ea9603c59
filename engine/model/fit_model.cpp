#include "model/fit_model.h"

#include <torch/torch.h>

#include "model/clip_cache.h"
#include "util/error.h"
#include "util/mapped.h"

namespace refocus {

torch::Tensor FitData::clip_array(at::IntArrayRef shape, const char* keep) const {
    if (keep && !cache_dir.empty()) return new_kept_array(*this, keep, shape);
    return mapped_dir.empty() ? torch::zeros(shape) : mapped_tensor(shape, mapped_dir);
}

bool finite_frame(const torch::Tensor& x) {
    return torch::isfinite(x).all().item<bool>();
}

bool finite_radius(const torch::Tensor& r) {
    return finite_frame(r) && !(r < 0).any().item<bool>();
}

void check_finite(const FitData& d) {
    for (int64_t t = 0; t < d.frames; ++t) {
        if (!d.input_finite && !finite_frame(d.input[t]))
            throw Error("fit: the input frames contain NaN/Inf");
        if (!d.radius_finite && !finite_radius(d.radius[t]))
            throw Error("fit: the radius maps contain NaN/Inf or negative values");
    }
}

torch::Tensor FitData::per_frame(const std::function<torch::Tensor(int64_t)>& fn) const {
    const torch::Tensor first = fn(0);
    std::vector<int64_t> shape{frames};
    for (int64_t s : first.sizes()) shape.push_back(s);
    torch::Tensor out = clip_array(shape);
    out[0].copy_(first);
    for (int64_t t = 1; t < frames; ++t) out[t].copy_(fn(t));
    return out;
}

void FitModel::load_state(const std::map<std::string, torch::Tensor>& s) {
    torch::NoGradGuard g;
    for (auto& [name, t] : state()) {
        auto it = s.find(name);
        if (it == s.end()) throw Error("checkpoint lacks tensor '" + name + "'");
        if (!it->second.sizes().equals(t.sizes()))
            throw Error("checkpoint tensor '" + name + "' has shape " +
                        c10::str(it->second.sizes()) + ", the model expects " +
                        c10::str(t.sizes()));
        t.copy_(it->second);
    }
}

Layers FitModel::render_padded(const std::vector<int64_t>& frames, int64_t pad) {
    if (pad > max_pad())
        throw Error("the " + preset() + " model renders at most " + std::to_string(max_pad()) +
                    " px beyond the frame (asked for " + std::to_string(pad) + ")");
    return render(frames);
}

void check_windows(const std::string& who, int64_t frames, int64_t height, int64_t width,
                   int64_t pad, const std::vector<int64_t>& x0, const std::vector<int64_t>& y0,
                   int64_t h, int64_t w) {
    if (int64_t(x0.size()) != frames || int64_t(y0.size()) != frames)
        throw Error(who + ": one window corner per frame expected (" + std::to_string(frames) +
                    " frames, " + std::to_string(x0.size()) + " corners)");
    for (size_t b = 0; b < x0.size(); ++b)
        if (h < 1 || w < 1 || x0[b] < -pad || y0[b] < -pad || x0[b] + w > width + pad ||
            y0[b] + h > height + pad)
            throw Error(who + ": window " + std::to_string(w) + "x" + std::to_string(h) + " at (" +
                        std::to_string(x0[b]) + ", " + std::to_string(y0[b]) +
                        ") reaches past the " + std::to_string(pad) + " px the model renders " +
                        "beyond the " + std::to_string(width) + "x" + std::to_string(height) +
                        " frame");
}

Layers FitModel::render_window(const std::vector<int64_t>& frames, const std::vector<int64_t>& x0,
                               const std::vector<int64_t>& y0, int64_t h, int64_t w) {
    const int64_t pad = max_pad();
    Layers full = render_padded(frames, pad);
    const int64_t H = full.sharp.size(2) - 2 * pad, W = full.sharp.size(3) - 2 * pad;
    check_windows("the " + preset() + " model", int64_t(frames.size()), H, W, pad, x0, y0, h, w);
    // Frame b's window of an image [B,C,·,·] (dy = 2) or a grid [B,·,·,2] (dy = 1).
    auto cut = [&](const torch::Tensor& x, int64_t dy) {
        if (!x.defined()) return x;
        std::vector<torch::Tensor> per;
        for (size_t b = 0; b < frames.size(); ++b)
            per.push_back(x[b].narrow(dy - 1, y0[b] + pad, h).narrow(dy, x0[b] + pad, w));
        return torch::stack(per);
    };
    Layers out;
    out.sharp = cut(full.sharp, 2);
    out.bg = cut(full.bg, 2);
    out.fg = cut(full.fg, 2);
    out.alpha = cut(full.alpha, 2);
    out.uv_bg = cut(full.uv_bg, 1);
    out.uv_fg = cut(full.uv_fg, 1);
    out.x0 = x0;
    out.y0 = y0;
    return out;
}

}  // namespace refocus
