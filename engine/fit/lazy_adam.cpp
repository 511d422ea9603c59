#include "fit/lazy_adam.h"

#include <torch/torch.h>

#include <cmath>

#include "util/error.h"

namespace refocus {

torch::Tensor LazyAdam::step(LossClosure closure) {
    torch::NoGradGuard no_grad;
    torch::Tensor loss;
    if (closure) {
        at::AutoGradMode grad(true);
        loss = closure();
    }
    for (auto& group : param_groups_) {
        auto& o = static_cast<torch::optim::AdamOptions&>(group.options());
        if (o.weight_decay() != 0 || o.amsgrad())
            throw Error("LazyAdam: weight decay and AMSGrad are not supported");
        const double b1 = std::get<0>(o.betas()), b2 = std::get<1>(o.betas());
        for (auto& p : group.params()) {
            if (!p.grad().defined()) continue;
            const auto& g = p.grad();
            const std::string key = c10::guts::to_string(p.unsafeGetTensorImpl());
            if (state_.find(key) == state_.end()) {
                auto s = std::make_unique<torch::optim::AdamParamState>();
                s->step(0);
                s->exp_avg(torch::zeros_like(p, torch::MemoryFormat::Preserve));
                s->exp_avg_sq(torch::zeros_like(p, torch::MemoryFormat::Preserve));
                state_[key] = std::move(s);
            }
            auto& s = static_cast<torch::optim::AdamParamState&>(*state_[key]);
            s.step(s.step() + 1);
            const double c1 = 1 - std::pow(b1, double(s.step())),
                         c2 = 1 - std::pow(b2, double(s.step()));
            auto touched = g != 0;
            auto& m = s.exp_avg();
            auto& v = s.exp_avg_sq();
            m.copy_(torch::where(touched, m * b1 + g * (1 - b1), m));
            v.copy_(torch::where(touched, v * b2 + g * g * (1 - b2), v));
            auto denom = (v.sqrt() / std::sqrt(c2)).add_(o.eps());
            p.sub_(torch::where(touched, m / denom, torch::zeros({}, m.options())) * (o.lr() / c1));
        }
    }
    return loss;
}

}  // namespace refocus
