// Torch binding of the per-frame Gaussian kernels (fracture_kernels.h). Python side:
// fracture_gs/fracture/ops.py.
#include "fracture/fracture_bind.h"

#include "fracture/fracture_kernels.h"

#ifdef FGS_WITH_CUDA
#include "bind_utils.h"
#endif

namespace fgs {
namespace {

using torch::Tensor;

#ifdef FGS_WITH_CUDA
constexpr auto kDeformCuda = fracture::deform_gaussians_cuda;
constexpr auto kLensCuda = fracture::lens_ellipsoids_cuda;
#else
constexpr void (*kDeformCuda)(const fracture::DeformInputs&, const fracture::DeformOutputs&, void*) = nullptr;
constexpr void (*kLensCuda)(const fracture::LensInputs&, const fracture::LensOutputs&, void*) = nullptr;
#endif

void check(const Tensor& t, const char* name, torch::ScalarType dtype,
           std::initializer_list<int64_t> shape, const Tensor& like) {
  TORCH_CHECK(t.scalar_type() == dtype && t.is_contiguous(), name, " must be a contiguous ",
              c10::toString(dtype), " tensor");
  TORCH_CHECK(t.sizes().equals(shape), name, " must have shape ", c10::IntArrayRef(shape),
              ", got ", t.sizes());
  TORCH_CHECK(t.device() == like.device(), name, " is on ", t.device(), ", expected ", like.device());
}

// Runs a kernel pair on the tensors' device: the CUDA launcher when they are on a GPU (and the
// extension has CUDA kernels), else the OpenMP loop.
template <class In, class Out>
void run_kernel(bool on_cuda, void (*cpu)(const In&, const Out&),
                void (*cuda)(const In&, const Out&, void*), const In& in, const Out& out) {
  if (on_cuda) {
#ifdef FGS_WITH_CUDA
    cuda(in, out, current_cuda_stream());
#else
    (void)cuda;
    TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
  } else {
    cpu(in, out);
  }
}

// (means (M,3), covariances (M,3,3), view_rotations (M,3,3)); see deform.h.
std::vector<Tensor> deform_gaussians(const Tensor& x, const Tensor& F, const Tensor& driver,
                                     const Tensor& rest_offset, const Tensor& rest_covariance,
                                     const Tensor& object_rotation, const Tensor& gaussian_object) {
  const int64_t n = x.size(0), m = driver.size(0), o = object_rotation.size(0);
  check(x, "x", torch::kFloat32, {n, 3}, x);
  check(F, "F_E", torch::kFloat32, {n, 3, 3}, x);
  check(driver, "driver", torch::kInt64, {m}, x);
  check(rest_offset, "rest_offset", torch::kFloat32, {m, 3}, x);
  check(rest_covariance, "rest_covariance", torch::kFloat32, {m, 3, 3}, x);
  check(object_rotation, "object_rotation", torch::kFloat32, {o, 3, 3}, x);
  check(gaussian_object, "gaussian_object", torch::kInt32, {m}, x);
  if (m > 0) {
    TORCH_CHECK(driver.min().item<int64_t>() >= 0 && driver.max().item<int64_t>() < n,
                "driver indices must be in [0, ", n, ")");
    TORCH_CHECK(gaussian_object.min().item<int32_t>() >= 0 && gaussian_object.max().item<int32_t>() < o,
                "gaussian_object must be in [0, ", o, ")");
  }
  Tensor means = torch::empty({m, 3}, x.options());
  Tensor covariances = torch::empty({m, 3, 3}, x.options());
  Tensor view_rotations = torch::empty({m, 3, 3}, x.options());
  fracture::DeformInputs in;
  in.num_gaussians = m;
  in.x = x.data_ptr<float>();
  in.F = F.data_ptr<float>();
  in.driver = driver.data_ptr<int64_t>();
  in.rest_offset = rest_offset.data_ptr<float>();
  in.rest_covariance = rest_covariance.data_ptr<float>();
  in.object_rotation = object_rotation.data_ptr<float>();
  in.gaussian_object = gaussian_object.data_ptr<int32_t>();
  const fracture::DeformOutputs out{means.data_ptr<float>(), covariances.data_ptr<float>(),
                                    view_rotations.data_ptr<float>()};
  run_kernel(x.is_cuda(), fracture::deform_gaussians_cpu, kDeformCuda, in, out);
  return {means, covariances, view_rotations};
}

// (centre (P,3), scales (P,3), rotation (P,3,3), covariance (P,3,3), valid (P,) bool); see mvee.h.
std::vector<Tensor> lens_ellipsoids(const Tensor& centre_i, const Tensor& radius_i,
                                    const Tensor& centre_j, const Tensor& radius_j, double k_sigma) {
  const int64_t p = centre_i.size(0);
  check(centre_i, "centre_i", torch::kFloat32, {p, 3}, centre_i);
  check(radius_i, "radius_i", torch::kFloat32, {p}, centre_i);
  check(centre_j, "centre_j", torch::kFloat32, {p, 3}, centre_i);
  check(radius_j, "radius_j", torch::kFloat32, {p}, centre_i);
  TORCH_CHECK(k_sigma > 0.0, "k_sigma must be > 0, got ", k_sigma);
  const auto fopt = centre_i.options();
  Tensor centre = torch::empty({p, 3}, fopt), scales = torch::empty({p, 3}, fopt);
  Tensor rotation = torch::empty({p, 3, 3}, fopt), covariance = torch::empty({p, 3, 3}, fopt);
  Tensor valid = torch::empty({p}, fopt.dtype(torch::kBool));
  const fracture::LensInputs in{p, centre_i.data_ptr<float>(), radius_i.data_ptr<float>(),
                                centre_j.data_ptr<float>(), radius_j.data_ptr<float>(), (float)k_sigma};
  const fracture::LensOutputs out{centre.data_ptr<float>(), scales.data_ptr<float>(),
                                  rotation.data_ptr<float>(), covariance.data_ptr<float>(),
                                  valid.data_ptr<bool>()};
  run_kernel(centre_i.is_cuda(), fracture::lens_ellipsoids_cpu, kLensCuda, in, out);
  return {centre, scales, rotation, covariance, valid};
}

}  // namespace

void register_fracture(pybind11::module& m) {
  m.def("fracture_deform_gaussians", &deform_gaussians,
        "Gaussians that follow their particles: F x offset, F Σ0 Fᵀ, polar rotation (fracture_gs/fracture/ops.py)");
  m.def("fracture_lens_ellipsoids", &lens_ellipsoids,
        "FPGO: ellipsoids of the overlaps of sphere pairs, docs/formulas.md §13 (fracture_gs/fracture/ops.py)");
}

}  // namespace fgs
