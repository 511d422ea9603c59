#include "io/tensor_image.h"

#include "util/error.h"

namespace refocus {

torch::Tensor image_to_tensor(const Image& img) {
    if (img.empty()) throw Error("cannot convert an empty image to a tensor");
    auto t = torch::from_blob(const_cast<float*>(img.data()), {img.height, img.width, img.channels},
                              torch::kFloat32);
    // clone(), not contiguous(): for one channel the permuted view is already contiguous, and
    // contiguous() would hand back a tensor aliasing img's memory (dangling once img is gone).
    return t.permute({2, 0, 1}).clone(at::MemoryFormat::Contiguous);
}

Image tensor_to_image(const torch::Tensor& t_in) {
    torch::Tensor t = t_in.detach().to(torch::kCPU, torch::kFloat32);
    if (t.dim() == 2) t = t.unsqueeze(0);
    if (t.dim() != 3) throw Error("tensor_to_image needs [C,H,W] or [H,W]");
    t = t.permute({1, 2, 0}).contiguous();
    Image img(static_cast<int>(t.size(1)), static_cast<int>(t.size(0)),
              static_cast<int>(t.size(2)));
    std::memcpy(img.data(), t.data_ptr<float>(), img.size() * sizeof(float));
    return img;
}

torch::Tensor stack_images(const std::vector<Image>& imgs) {
    std::vector<torch::Tensor> ts;
    ts.reserve(imgs.size());
    for (const auto& i : imgs) ts.push_back(image_to_tensor(i));
    return torch::stack(ts);
}

}  // namespace refocus
