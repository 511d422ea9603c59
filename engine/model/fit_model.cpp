#include "model/fit_model.h"

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

}  // namespace refocus
