#include "fit/perframe_model.h"

#include <torch/torch.h>

#include "util/error.h"

namespace refocus {

PerframeModel::PerframeModel(const FitData& d, const PerframeOptions& opts)
    : m_data(d), m_opts(opts) {
    m_sharp = d.input.clone();
    m_done = torch::zeros({d.frames}, torch::kUInt8);
}

Layers PerframeModel::render(const std::vector<int64_t>& frames) {
    Layers L;
    L.sharp = m_sharp.index_select(0, torch::tensor(frames, torch::kLong));
    L.bg = L.sharp;
    return L;
}

torch::Tensor PerframeModel::priors(const Layers&, const std::vector<int64_t>&, int64_t,
                                    LossTerms&) {
    return torch::zeros({});
}

torch::Tensor PerframeModel::atlas_bg() {
    throw Error("the perframe preset has no atlas (it deconvolves each frame alone)");
}
torch::Tensor PerframeModel::atlas_fg() {
    return atlas_bg();
}
void PerframeModel::set_atlas_bg(const torch::Tensor&) {
    atlas_bg();
}
void PerframeModel::set_atlas_fg(const torch::Tensor&) {
    atlas_bg();
}

std::map<std::string, torch::Tensor> PerframeModel::state() {
    return {{"sharp", m_sharp}, {"done", m_done}};
}

void PerframeModel::step_itself(int64_t t, std::mutex& commit) {
    if (t < 0 || t >= m_data.frames) return;
    TvDeconvOptions o;
    o.blur = m_data.blur;
    o.iterations = m_opts.iterations;
    o.lambda = m_opts.lambda;
    auto u = deconvolve_tv(m_data.input[t], m_data.radius[t], o);
    std::lock_guard<std::mutex> lock(commit);
    m_sharp[t].copy_(u);
    m_done[t] = 1;
}

bool PerframeModel::frame_done(int t) const {
    return t >= 0 && t < m_data.frames && m_done[t].item<uint8_t>() != 0;
}

}  // namespace refocus
