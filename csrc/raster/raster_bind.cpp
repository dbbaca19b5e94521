// Torch binding of the Gaussian rasterizer: checks tensors, allocates every buffer and runs
// the framework-free kernel phases of raster_kernels.h on the CPU or (when compiled) CUDA.
// The Python autograd Function (fracture_gs/render/rasterize.py) calls raster_forward and
// keeps its state tensors for raster_backward.
#include "raster/raster_bind.h"

#include <optional>
#include <vector>

#include "bound_error.h"
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

// Throws unless t holds `per_gaussian` values for each of the n Gaussians (the kernels read row
// i of every input for Gaussian i).
void check_rows(const torch::Tensor& t, const char* name, int64_t n, int64_t per_gaussian) {
  TORCH_CHECK(t.dim() >= 1 && t.size(0) == n && t.numel() == n * per_gaussian, "rasterize: ", name, " must have ",
              per_gaussian, " values for each of the ", n, " Gaussians, got shape ", t.sizes());
}

// The group rule's next[] (exclusive_next) must link the members of each group in a ring:
// entries -1 or a Gaussian index, and every member the next of exactly one member. The kernels
// follow next[] until they are back at the Gaussian they started from.
void check_group_rings(const torch::Tensor& next, int64_t n) {
  if (!next.device().is_cpu()) {
    const torch::Tensor valid = next.ge(-1).logical_and(next.lt(n)).all();
    TORCH_CHECK(valid.item<bool>(), "rasterize: exclusive_next entries must be -1 or Gaussian indices");
    const torch::Tensor members = next.ge(0);
    const torch::Tensor targets = next.masked_select(members).to(torch::kInt64);
    const torch::Tensor hits = torch::bincount(targets, {}, n);
    TORCH_CHECK(hits.eq(members.to(torch::kInt64)).all().item<bool>(),
                "rasterize: exclusive_next must link each group's members in a ring");
    return;
  }
  const int32_t* v = next.data_ptr<int32_t>();
  std::vector<uint8_t> hit(n, 0);
  for (int64_t i = 0; i < n; ++i) {
    TORCH_CHECK(v[i] >= -1 && v[i] < n, "rasterize: exclusive_next[", i, "] = ", v[i],
                " is neither -1 nor a Gaussian index");
    if (v[i] < 0) continue;
    TORCH_CHECK(!hit[v[i]] && v[v[i]] >= 0, "rasterize: exclusive_next must link each group's members in a ring ",
                "(Gaussian ", v[i], ")");
    hit[v[i]] = 1;
  }
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
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "rasterize: means must have shape (N, 3)");
  const int64_t n = means.size(0);
  if (n > kMaxInt32Count)
    throw_bound_error("rasterize: ", n, " Gaussians are more than the rasterizer's int32 indices address");
  check_rows(opacities, "opacities", n, 1);
  if (scales) check_rows(*scales, "scales", n, 3);
  if (quats) check_rows(*quats, "quats", n, 4);
  if (covariances) check_rows(*covariances, "covariances", n, 9);
  if (colors) check_rows(*colors, "colors", n, 3);
  if (view_rotations) check_rows(*view_rotations, "view_rotations", n, 9);
  GaussianInputs in;
  in.num = n;
  in.means = means.data_ptr<float>();
  in.opacities = opacities.data_ptr<float>();
  in.scales = fptr(scales);
  in.quats = fptr(quats);
  in.covariances = fptr(covariances);
  in.sh = fptr(sh);
  in.colors = fptr(colors);
  in.view_rotations = fptr(view_rotations);
  if (sh.has_value()) {
    TORCH_CHECK(sh->dim() == 3 && sh->size(2) == 3, "rasterize: sh must have shape (N, K, 3)");
    check_rows(*sh, "sh", n, 3 * sh->size(1));
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
    check_rows(*exclusive, "exclusive", n, 1);
    in.exclusive.flags = exclusive->data_ptr<uint8_t>();
  }
  if (exclusive_next.has_value()) {
    TORCH_CHECK(!exclusive.has_value(), "rasterize: give exclusive flags or groups, not both");
    TORCH_CHECK(exclusive_next->scalar_type() == torch::kInt32 && exclusive_next->is_contiguous() &&
                    exclusive_next->device() == device && exclusive_next->numel() == in.num,
                "rasterize: exclusive_next must be a contiguous int32 (N,) tensor on the means' device");
    check_group_rings(*exclusive_next, n);
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

// The tile lists hold one int32 slot per (Gaussian, tile) pair that a Gaussian's footprint
// covers: huge footprints on a large image can need more than int32 counts.
void check_slot_count(int64_t total, int64_t n) {
  if (total > kMaxInt32Count)
    throw_bound_error("rasterize: the footprints of ", n, " Gaussians cover ", total, " (Gaussian, tile) pairs, more "
                      "than the rasterizer's int32 tile lists hold (", kMaxInt32Count, "); render a smaller image "
                      "or fewer, smaller Gaussians");
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
    check_slot_count(total, N);
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
    check_slot_count(total, N);
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

// The forward's state handed to the backward must be that of these Gaussians and this image:
// the backward indexes the Gaussians, slots and pixels with it.
void check_forward_state(int64_t n, int64_t tiles, int64_t width, int64_t height, const torch::Tensor& proj,
                         const torch::Tensor& slot_offset, const torch::Tensor& tile_start,
                         const torch::Tensor& tile_slots, const torch::Tensor& slot_gaussian,
                         const torch::Tensor& final_T, const torch::Tensor& n_contrib, const torch::Tensor& winner,
                         const torch::Tensor& grad_rgb, const torch::Tensor& grad_alpha,
                         const torch::Tensor& grad_depth) {
  const int64_t total = tile_slots.numel(), pixels = width * height;
  TORCH_CHECK(proj.numel() == n * raster::kProjStride && slot_offset.numel() == n + 1 &&
                  tile_start.numel() == tiles + 1 && slot_gaussian.numel() == total && total <= kMaxInt32Count &&
                  final_T.numel() == pixels && n_contrib.numel() == pixels && winner.numel() == pixels &&
                  grad_rgb.numel() == 3 * pixels && grad_alpha.numel() == pixels && grad_depth.numel() == pixels,
              "rasterize backward: the forward state does not belong to these ", n, " Gaussians and this ", width,
              "x", height, " image");
  for (const torch::Tensor* t : {&tile_start, &tile_slots, &slot_gaussian, &n_contrib, &winner})
    TORCH_CHECK(t->scalar_type() == torch::kInt32 && t->is_contiguous() && t->device() == proj.device(),
                "rasterize backward: the forward state must be contiguous int32 tensors on the means' device");
  TORCH_CHECK(slot_offset.scalar_type() == torch::kInt64 && slot_offset.is_contiguous(),
              "rasterize backward: slot_offset must be a contiguous int64 tensor");
  if (!proj.device().is_cpu()) return;
  const int32_t* start = tile_start.data_ptr<int32_t>();
  TORCH_CHECK(start[0] == 0 && start[tiles] == total, "rasterize backward: tile_start does not span the tile slots");
  for (int64_t t = 0; t < tiles; ++t)
    TORCH_CHECK(start[t + 1] >= start[t], "rasterize backward: tile_start decreases at tile ", t);
  TORCH_CHECK(first_outside(tile_slots.data_ptr<int32_t>(), total, total) < 0 &&
                  first_outside(slot_gaussian.data_ptr<int32_t>(), total, n) < 0,
              "rasterize backward: the tile lists name slots or Gaussians that do not exist");
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
  check_forward_state(in.num, (int64_t)tiles_x * tiles_y, width, height, proj, slot_offset, tile_start, tile_slots,
                      slot_gaussian, final_T, n_contrib, winner, grad_rgb, grad_alpha, grad_depth);
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
