// Torch binding of the Gaussian rasterizer: checks tensors, allocates every buffer and runs
// the framework-free kernel phases of raster_kernels.h on the CPU or (when compiled) CUDA.
// The Python autograd Function (fracture_gs/render/rasterize.py) calls raster_forward and
// keeps its state tensors for raster_backward.
#include "raster/raster_bind.h"

#include <optional>
#include <vector>

#include "common/blend.h"
#include "raster/raster_kernels.h"

#ifdef FGS_WITH_CUDA
#include "bind_utils.h"
#endif

namespace fgs {
namespace {

using OptTensor = std::optional<torch::Tensor>;
using raster::CameraParams;
using raster::GaussianGrads;
using raster::GaussianInputs;

const float* fptr(const OptTensor& t) { return t.has_value() ? t->data_ptr<float>() : nullptr; }

void check_float(const torch::Tensor& t, const char* name, const torch::Device& device) {
  TORCH_CHECK(t.scalar_type() == torch::kFloat32, "rasterize: ", name, " must be float32");
  TORCH_CHECK(t.is_contiguous(), "rasterize: ", name, " must be contiguous");
  TORCH_CHECK(t.device() == device, "rasterize: ", name, " is on ", t.device(), ", expected ",
              device);
}

void check_opt(const OptTensor& t, const char* name, const torch::Device& device) {
  if (t.has_value()) check_float(*t, name, device);
}

CameraParams make_camera(const torch::Tensor& world_to_camera, double fx, double fy, double cx,
                         double cy, int64_t width, int64_t height, double near_plane) {
  const torch::Tensor m = world_to_camera.to(torch::kCPU, torch::kFloat64).contiguous();
  TORCH_CHECK(m.dim() == 2 && m.size(0) == 4 && m.size(1) == 4,
              "rasterize: world_to_camera must be 4x4");
  const double* w = m.data_ptr<double>();
  CameraParams cam;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.R[3 * r + c] = (float)w[4 * r + c];
    cam.t[r] = (float)w[4 * r + 3];
  }
  for (int c = 0; c < 3; ++c)  // centre = -Rᵀ t
    cam.center[c] = (float)-(w[c] * w[3] + w[4 + c] * w[7] + w[8 + c] * w[11]);
  cam.fx = (float)fx; cam.fy = (float)fy; cam.cx = (float)cx; cam.cy = (float)cy;
  cam.width = (int)width; cam.height = (int)height;
  cam.near_plane = (float)near_plane;
  return cam;
}

GaussianInputs make_inputs(const torch::Tensor& means, const torch::Tensor& opacities,
                           const OptTensor& scales, const OptTensor& quats,
                           const OptTensor& covariances, const OptTensor& sh,
                           const OptTensor& colors, const OptTensor& exclusive,
                           const OptTensor& exclusive_next, const OptTensor& view_rotations) {
  const torch::Device device = means.device();
  check_float(means, "means", device);
  check_float(opacities, "opacities", device);
  check_opt(scales, "scales", device);
  check_opt(quats, "quats", device);
  check_opt(covariances, "covariances", device);
  check_opt(sh, "sh", device);
  check_opt(colors, "colors", device);
  check_opt(view_rotations, "view_rotations", device);
  TORCH_CHECK(covariances.has_value() != (scales.has_value() && quats.has_value()),
              "rasterize: give either scales+quats or covariances");
  TORCH_CHECK(sh.has_value() != colors.has_value(), "rasterize: give either sh or colors");
  GaussianInputs in;
  in.num = means.size(0);
  in.means = means.data_ptr<float>();
  in.opacities = opacities.data_ptr<float>();
  in.scales = fptr(scales);
  in.quats = fptr(quats);
  in.covariances = fptr(covariances);
  in.sh = fptr(sh);
  in.colors = fptr(colors);
  in.view_rotations = fptr(view_rotations);
  if (sh.has_value()) {
    const int64_t K = sh->size(1);
    int degree = 0;
    while ((degree + 1) * (degree + 1) < K) ++degree;
    TORCH_CHECK((degree + 1) * (degree + 1) == K && degree <= 3,
                "rasterize: sh must have K = 1, 4, 9 or 16 coefficients");
    in.sh_degree = degree;
  }
  if (exclusive.has_value()) {
    TORCH_CHECK(exclusive->scalar_type() == torch::kUInt8 && exclusive->is_contiguous() &&
                    exclusive->device() == device,
                "rasterize: exclusive must be a contiguous uint8 tensor on the means' device");
    in.exclusive.flags = exclusive->data_ptr<uint8_t>();
  }
  if (exclusive_next.has_value()) {
    TORCH_CHECK(!exclusive.has_value(), "rasterize: give exclusive flags or groups, not both");
    TORCH_CHECK(exclusive_next->scalar_type() == torch::kInt32 && exclusive_next->is_contiguous() &&
                    exclusive_next->device() == device && exclusive_next->numel() == in.num,
                "rasterize: exclusive_next must be a contiguous int32 (N,) tensor on the means' device");
    in.exclusive.next = exclusive_next->data_ptr<int32_t>();
  }
  return in;
}

// The exclusive rule of `in` for the kernels; for the group rule with its per-camera summary
// (ExclusiveRule::earlier), computed from proj into `earlier` (which must outlive the rule).
raster::ExclusiveRule exclusive_rule(const GaussianInputs& in, const torch::Tensor& proj,
                                     torch::Tensor& earlier) {
  raster::ExclusiveRule rule = in.exclusive;
  if (rule.next == nullptr) return rule;
  earlier = torch::empty({in.num}, proj.options().dtype(torch::kInt32));
  if (proj.is_cuda()) {
#ifdef FGS_WITH_CUDA
    raster::group_earlier_cuda(in.num, proj.data_ptr<float>(), rule.next,
                               earlier.data_ptr<int32_t>(), current_cuda_stream());
#endif
  } else {
    raster::group_earlier_cpu(in.num, proj.data_ptr<float>(), rule.next, earlier.data_ptr<int32_t>());
  }
  rule.earlier = earlier.data_ptr<int32_t>();
  return rule;
}

// Returns (rgb, alpha, depth, radii, proj, slot_offset, tile_start, tile_slots,
// slot_gaussian, final_T, n_contrib, exclusive_winner).
std::vector<torch::Tensor> raster_forward(
    const torch::Tensor& means, const torch::Tensor& opacities, const OptTensor& scales,
    const OptTensor& quats, const OptTensor& covariances, const OptTensor& sh,
    const OptTensor& colors, const OptTensor& exclusive, const OptTensor& exclusive_next,
    const OptTensor& view_rotations,
    const torch::Tensor& background, const torch::Tensor& world_to_camera, double fx, double fy,
    double cx, double cy, int64_t width, int64_t height, double near_plane) {
  const GaussianInputs in = make_inputs(means, opacities, scales, quats, covariances, sh, colors,
                                        exclusive, exclusive_next, view_rotations);
  const CameraParams cam = make_camera(world_to_camera, fx, fy, cx, cy, width, height, near_plane);
  const torch::Tensor bg = background.to(torch::kCPU, torch::kFloat32).contiguous();
  TORCH_CHECK(bg.numel() == 3, "rasterize: background must have 3 values");
  const auto fopt = means.options();
  const auto iopt = means.options().dtype(torch::kInt32);
  const int64_t N = in.num;
  const int tiles_x = raster::tiles_along(cam.width), tiles_y = raster::tiles_along(cam.height);
  torch::Tensor proj = torch::empty({N, raster::kProjStride}, fopt);
  torch::Tensor rect = torch::empty({N, 4}, iopt);
  torch::Tensor radii = torch::empty({N}, iopt);
  torch::Tensor tiles_touched = torch::empty({N}, iopt);
  torch::Tensor slot_offset = torch::empty({N + 1}, means.options().dtype(torch::kInt64));
  torch::Tensor tile_start = torch::empty({(int64_t)tiles_x * tiles_y + 1}, iopt);
  torch::Tensor rgb = torch::empty({height, width, 3}, fopt);
  torch::Tensor alpha = torch::empty({height, width}, fopt);
  torch::Tensor depth = torch::empty({height, width}, fopt);
  torch::Tensor final_T = torch::empty({height, width}, fopt);
  torch::Tensor n_contrib = torch::empty({height, width}, iopt);
  torch::Tensor winner = torch::empty({height, width}, iopt);
  raster::PixelState state{final_T.data_ptr<float>(), n_contrib.data_ptr<int32_t>(),
                           winner.data_ptr<int32_t>()};
  torch::Tensor tile_slots, slot_gaussian, earlier;
  if (means.is_cuda()) {
#ifdef FGS_WITH_CUDA
    void* stream = current_cuda_stream();
    raster::preprocess_cuda(cam, in, proj.data_ptr<float>(), rect.data_ptr<int32_t>(),
                            radii.data_ptr<int32_t>(), tiles_touched.data_ptr<int32_t>(), stream);
    const size_t scan_bytes = raster::slot_offsets_scratch_bytes_cuda(N);
    torch::Tensor scan_scratch = torch::empty({(int64_t)scan_bytes + 1}, means.options().dtype(torch::kUInt8));
    const int64_t total = raster::slot_offsets_cuda(N, tiles_touched.data_ptr<int32_t>(),
                                                    slot_offset.data_ptr<int64_t>(),
                                                    scan_scratch.data_ptr(), scan_bytes, stream);
    tile_slots = torch::empty({total}, iopt);
    slot_gaussian = torch::empty({total}, iopt);
    torch::Tensor keys = torch::empty({2 * total + 1}, means.options().dtype(torch::kInt64));
    torch::Tensor values = torch::empty({2 * total + 1}, iopt);
    const size_t sort_bytes = raster::sort_scratch_bytes_cuda(total);
    torch::Tensor sort_scratch = torch::empty({(int64_t)sort_bytes + 1}, means.options().dtype(torch::kUInt8));
    raster::bin_cuda(cam, N, proj.data_ptr<float>(), rect.data_ptr<int32_t>(),
                     slot_offset.data_ptr<int64_t>(), total, tile_start.data_ptr<int32_t>(),
                     tile_slots.data_ptr<int32_t>(), slot_gaussian.data_ptr<int32_t>(),
                     reinterpret_cast<uint64_t*>(keys.data_ptr<int64_t>()), values.data_ptr<int32_t>(),
                     sort_scratch.data_ptr(), sort_bytes, stream);
    const raster::TileBins bins{tiles_x, tiles_y, tile_start.data_ptr<int32_t>(),
                                tile_slots.data_ptr<int32_t>(), slot_gaussian.data_ptr<int32_t>()};
    raster::render_forward_cuda(cam, proj.data_ptr<float>(), exclusive_rule(in, proj, earlier), bins, bg.data_ptr<float>(),
                                rgb.data_ptr<float>(), alpha.data_ptr<float>(),
                                depth.data_ptr<float>(), state, stream);
#else
    TORCH_CHECK(false, "rasterize: fracture_gs._C was built without CUDA kernels");
#endif
  } else {
    raster::preprocess_cpu(cam, in, proj.data_ptr<float>(), rect.data_ptr<int32_t>(),
                           radii.data_ptr<int32_t>(), tiles_touched.data_ptr<int32_t>());
    const int64_t total = raster::slot_offsets_cpu(N, tiles_touched.data_ptr<int32_t>(),
                                                   slot_offset.data_ptr<int64_t>());
    tile_slots = torch::empty({total}, iopt);
    slot_gaussian = torch::empty({total}, iopt);
    raster::bin_cpu(cam, N, proj.data_ptr<float>(), rect.data_ptr<int32_t>(),
                    slot_offset.data_ptr<int64_t>(), tile_start.data_ptr<int32_t>(),
                    tile_slots.data_ptr<int32_t>(), slot_gaussian.data_ptr<int32_t>());
    const raster::TileBins bins{tiles_x, tiles_y, tile_start.data_ptr<int32_t>(),
                                tile_slots.data_ptr<int32_t>(), slot_gaussian.data_ptr<int32_t>()};
    raster::render_forward_cpu(cam, proj.data_ptr<float>(), exclusive_rule(in, proj, earlier), bins, bg.data_ptr<float>(),
                               rgb.data_ptr<float>(), alpha.data_ptr<float>(),
                               depth.data_ptr<float>(), state);
  }
  return {rgb, alpha, depth, radii, proj, slot_offset, tile_start, tile_slots, slot_gaussian,
          final_T, n_contrib, winner};
}

// Returns gradients (means, opacities, scales, quats, covariances, sh, colors,
// view_rotations, means2d); inputs that were not given get an undefined tensor.
std::vector<torch::Tensor> raster_backward(
    const torch::Tensor& means, const torch::Tensor& opacities, const OptTensor& scales,
    const OptTensor& quats, const OptTensor& covariances, const OptTensor& sh,
    const OptTensor& colors, const OptTensor& exclusive, const OptTensor& exclusive_next,
    const OptTensor& view_rotations,
    const torch::Tensor& background, const torch::Tensor& world_to_camera, double fx, double fy,
    double cx, double cy, int64_t width, int64_t height, double near_plane,
    const torch::Tensor& proj, const torch::Tensor& slot_offset, const torch::Tensor& tile_start,
    const torch::Tensor& tile_slots, const torch::Tensor& slot_gaussian,
    const torch::Tensor& final_T, const torch::Tensor& n_contrib, const torch::Tensor& winner,
    const torch::Tensor& grad_rgb, const torch::Tensor& grad_alpha,
    const torch::Tensor& grad_depth) {
  const GaussianInputs in = make_inputs(means, opacities, scales, quats, covariances, sh, colors,
                                        exclusive, exclusive_next, view_rotations);
  const CameraParams cam = make_camera(world_to_camera, fx, fy, cx, cy, width, height, near_plane);
  const torch::Tensor bg = background.to(torch::kCPU, torch::kFloat32).contiguous();
  const torch::Device device = means.device();
  check_float(grad_rgb, "grad_rgb", device);
  check_float(grad_alpha, "grad_alpha", device);
  check_float(grad_depth, "grad_depth", device);
  const int tiles_x = raster::tiles_along(cam.width), tiles_y = raster::tiles_along(cam.height);
  const int64_t total = tile_slots.numel();
  torch::Tensor slot_grads = torch::zeros({total, raster::kSlotStride}, means.options());
  auto like = [](const OptTensor& t) { return t.has_value() ? torch::zeros_like(*t) : torch::Tensor(); };
  torch::Tensor g_means = torch::zeros_like(means), g_opacities = torch::zeros_like(opacities);
  torch::Tensor g_scales = like(scales), g_quats = like(quats), g_cov = like(covariances);
  torch::Tensor g_sh = like(sh), g_colors = like(colors), g_view = like(view_rotations);
  torch::Tensor g_means2d = torch::zeros({in.num, 2}, means.options());
  auto ptr = [](torch::Tensor& t) { return t.defined() ? t.data_ptr<float>() : nullptr; };
  GaussianGrads grads;
  grads.means = ptr(g_means); grads.opacities = ptr(g_opacities); grads.scales = ptr(g_scales);
  grads.quats = ptr(g_quats); grads.covariances = ptr(g_cov); grads.sh = ptr(g_sh);
  grads.colors = ptr(g_colors); grads.view_rotations = ptr(g_view); grads.means2d = ptr(g_means2d);
  const raster::TileBins bins{tiles_x, tiles_y, tile_start.data_ptr<int32_t>(),
                              tile_slots.data_ptr<int32_t>(), slot_gaussian.data_ptr<int32_t>()};
  const raster::PixelState state{const_cast<float*>(final_T.data_ptr<float>()),
                                 const_cast<int32_t*>(n_contrib.data_ptr<int32_t>()),
                                 const_cast<int32_t*>(winner.data_ptr<int32_t>())};
  torch::Tensor earlier;
  if (means.is_cuda()) {
#ifdef FGS_WITH_CUDA
    void* stream = current_cuda_stream();
    raster::render_backward_cuda(cam, proj.data_ptr<float>(), exclusive_rule(in, proj, earlier), bins, bg.data_ptr<float>(),
                                 state, grad_rgb.data_ptr<float>(), grad_alpha.data_ptr<float>(),
                                 grad_depth.data_ptr<float>(), slot_grads.data_ptr<float>(), stream);
    raster::preprocess_backward_cuda(cam, in, proj.data_ptr<float>(), slot_offset.data_ptr<int64_t>(),
                                     slot_grads.data_ptr<float>(), grads, stream);
#else
    TORCH_CHECK(false, "rasterize: fracture_gs._C was built without CUDA kernels");
#endif
  } else {
    raster::render_backward_cpu(cam, proj.data_ptr<float>(), exclusive_rule(in, proj, earlier), bins, bg.data_ptr<float>(),
                                state, grad_rgb.data_ptr<float>(), grad_alpha.data_ptr<float>(),
                                grad_depth.data_ptr<float>(), slot_grads.data_ptr<float>());
    raster::preprocess_backward_cpu(cam, in, proj.data_ptr<float>(), slot_offset.data_ptr<int64_t>(),
                                    slot_grads.data_ptr<float>(), grads);
  }
  return {g_means, g_opacities, g_scales, g_quats, g_cov, g_sh, g_colors, g_view, g_means2d};
}

}  // namespace

void register_raster(pybind11::module& m) {
  m.def("raster_forward", &raster_forward,
        "Gaussian rasterizer forward (see fracture_gs/render/rasterize.py)");
  m.def("raster_backward", &raster_backward,
        "Gaussian rasterizer backward (see fracture_gs/render/rasterize.py)");
}

}  // namespace fgs
