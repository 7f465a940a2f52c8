// Exposes a peer rasterizer's C++ CPU functions to Python for benches/bench_peer.py.
// Only declarations come from the peer's `bindings.h`; its source is compiled from the
// user's checkout and never kept in this repository.
#include <torch/extension.h>

#include <memory>

#include "bindings.h"

namespace {

// Owns the per-pixel Gaussian lists that the peer's forward allocates with new[] and its
// backward reads: freed when Python drops the handle, whether or not backward ran.
struct PixelLists {
    std::vector<int32_t> *lists = nullptr;
    ~PixelLists() { delete[] lists; }
};

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor> project(
    torch::Tensor means, torch::Tensor scales, torch::Tensor quats, torch::Tensor viewmat,
    torch::Tensor projmat, float fx, float fy, float cx, float cy, int height, int width) {
    return project_gaussians_forward_tensor_cpu(static_cast<int>(means.size(0)), means, scales,
                                                1.0f, quats, viewmat, projmat, fx, fy, cx, cy,
                                                height, width, 0.01f);
}

std::tuple<torch::Tensor, torch::Tensor, std::shared_ptr<PixelLists>> rasterize_forward(
    int width, int height, const torch::Tensor &xys, const torch::Tensor &conics,
    const torch::Tensor &colors, const torch::Tensor &opacities, const torch::Tensor &background,
    const torch::Tensor &cov2d, const torch::Tensor &depths) {
    auto out = rasterize_forward_tensor_cpu(width, height, xys.contiguous(), conics.contiguous(),
                                            colors.contiguous(), opacities.contiguous(),
                                            background, cov2d.contiguous(), depths.contiguous());
    auto lists = std::make_shared<PixelLists>();
    lists->lists = std::get<2>(out);
    return {std::get<0>(out), std::get<1>(out), lists};
}

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor> rasterize_backward(
    int height, int width, const torch::Tensor &xys, const torch::Tensor &conics,
    const torch::Tensor &colors, const torch::Tensor &opacities, const torch::Tensor &background,
    const torch::Tensor &cov2d, const torch::Tensor &depths, const torch::Tensor &final_ts,
    const PixelLists &lists, const torch::Tensor &v_image, const torch::Tensor &v_alpha) {
    return rasterize_backward_tensor_cpu(height, width, xys.contiguous(), conics.contiguous(),
                                         colors.contiguous(), opacities.contiguous(), background,
                                         cov2d.contiguous(), depths.contiguous(), final_ts,
                                         lists.lists, v_image, v_alpha);
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    py::class_<PixelLists, std::shared_ptr<PixelLists>>(m, "PixelLists");
    m.def("project", &project);
    m.def("rasterize_forward", &rasterize_forward);
    m.def("rasterize_backward", &rasterize_backward);
}
