#include "fit/fit_model.h"

#include <torch/torch.h>

#include "util/error.h"

namespace refocus {

void FitModel::load_state(const std::map<std::string, torch::Tensor>& s) {
    torch::NoGradGuard g;
    for (auto& [name, t] : state()) {
        auto it = s.find(name);
        if (it == s.end()) throw Error("checkpoint lacks tensor '" + name + "'");
        if (!it->second.sizes().equals(t.sizes()))
            throw Error("checkpoint tensor '" + name + "' has shape " +
                        c10::str(it->second.sizes()) + ", the model expects " + c10::str(t.sizes()));
        t.copy_(it->second);
    }
}

}  // namespace refocus
