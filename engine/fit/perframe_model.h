#pragma once
// The `perframe` preset as a FitModel: the baseline that deconvolves each frame alone (non-blind
// MAP deconvolution with a TV prior, perframe.h), one frame a step, with no atlas. Frames not
// reached keep the input.
#include "model/fit_model.h"
#include "fit/perframe.h"

namespace refocus {

class PerframeModel : public FitModel {
  public:
    PerframeModel(const FitData& data, const PerframeOptions& opts);
    std::string preset() const override { return "perframe"; }
    std::vector<ParamGroup> param_groups() override { return {}; }
    Layers render(const std::vector<int64_t>& frames) override;
    torch::Tensor priors(const Layers&, const std::vector<int64_t>&, int64_t, LossTerms&) override;
    torch::Tensor atlas_bg() override;
    torch::Tensor atlas_fg() override;
    void set_atlas_bg(const torch::Tensor&) override;
    void set_atlas_fg(const torch::Tensor&) override;
    std::map<std::string, torch::Tensor> state() override;

    bool steps_itself() const override { return true; }
    void step_itself(int64_t step, std::mutex& commit) override;
    int64_t step_count() const override { return m_data.frames; }
    bool frame_done(int t) const override;

  private:
    const FitData& m_data;
    PerframeOptions m_opts;
    torch::Tensor m_sharp;  // [T,3,H,W] linear light: the input until a frame is deconvolved
    torch::Tensor m_done;   // [T] uint8, 1 where the frame was deconvolved
};

}  // namespace refocus
