#pragma once
// Adam that moves only the entries whose gradient is not zero this step ("lazy" Adam, as
// TensorFlow's LazyAdam for embeddings): their moments are updated and the step taken, the
// others keep their moments and stay where they are. The crop step (docs/method.md, Crops)
// trains a crop's texels each step; plain Adam's momentum would carry every texel a crop once
// reached on by up to ~5 steps' worth with no data under it, and the atlas drifts. The state
// is Adam's own (AdamParamState), so checkpoints hold it alike; bias correction counts the
// steps of the parameter, as TensorFlow's does.
#include <torch/optim/adam.h>

namespace refocus {

class LazyAdam : public torch::optim::Adam {
  public:
    using torch::optim::Adam::Adam;
    torch::Tensor step(LossClosure closure = nullptr) override;
};

}  // namespace refocus
