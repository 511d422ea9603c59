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
            // Only the touched entries (a crop's few boxes of each atlas) are read and written:
            // the cost follows the crop, bar one pass to find them.
            auto at = g.flatten().nonzero().squeeze(1);
            if (at.numel() == 0) continue;
            auto m = s.exp_avg().view({-1}), v = s.exp_avg_sq().view({-1});
            auto gi = g.flatten().index_select(0, at);
            auto mi = m.index_select(0, at).mul_(b1).add_(gi, 1 - b1);
            auto vi = v.index_select(0, at).mul_(b2).addcmul_(gi, gi, 1 - b2);
            m.index_copy_(0, at, mi);
            v.index_copy_(0, at, vi);
            auto step = mi.div_(vi.sqrt_().div_(std::sqrt(c2)).add_(o.eps())).mul_(-o.lr() / c1);
            p.view({-1}).index_add_(0, at, step);
        }
    }
    return loss;
}

}  // namespace refocus
