// Framework-free interface of the per-frame Gaussian kernels: Gaussians that follow their
// particles (deform.h) and the FPGO lens ellipsoids (common/mvee.h). Raw pointers, float32,
// row-major 3x3 matrices; one output row per input row, so results are deterministic.
#pragma once
#include <cstdint>

namespace fgs {
namespace fracture {

struct DeformInputs {
  int64_t num_gaussians = 0;
  const float* x = nullptr;                  // (N, 3) particle positions
  const float* F = nullptr;                  // (N, 3, 3) elastic deformation gradients
  const int64_t* driver = nullptr;           // (M,) particle of each Gaussian
  const float* rest_offset = nullptr;        // (M, 3)
  const float* rest_covariance = nullptr;    // (M, 3, 3)
  const float* object_rotation = nullptr;    // (O, 3, 3)
  const int32_t* gaussian_object = nullptr;  // (M,) row of object_rotation
};

struct DeformOutputs {
  float* means = nullptr;           // (M, 3)
  float* covariances = nullptr;     // (M, 3, 3)
  float* view_rotations = nullptr;  // (M, 3, 3)
};

struct LensInputs {
  int64_t num_pairs = 0;
  const float* centre_i = nullptr;  // (P, 3)
  const float* radius_i = nullptr;  // (P,)
  const float* centre_j = nullptr;  // (P, 3)
  const float* radius_j = nullptr;  // (P,)
  float k_sigma = 2.f;
};

struct LensOutputs {
  float* centre = nullptr;      // (P, 3)
  float* scales = nullptr;      // (P, 3)
  float* rotation = nullptr;    // (P, 3, 3)
  float* covariance = nullptr;  // (P, 3, 3)
  bool* valid = nullptr;        // (P,)
};

void deform_gaussians_cpu(const DeformInputs& in, const DeformOutputs& out);
void lens_ellipsoids_cpu(const LensInputs& in, const LensOutputs& out);

#ifdef FGS_WITH_CUDA
void deform_gaussians_cuda(const DeformInputs& in, const DeformOutputs& out, void* stream);
void lens_ellipsoids_cuda(const LensInputs& in, const LensOutputs& out, void* stream);
#endif

}  // namespace fracture
}  // namespace fgs
