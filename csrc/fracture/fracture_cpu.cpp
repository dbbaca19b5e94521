// CPU (OpenMP) loops of the per-frame Gaussian kernels (math in fracture_one.h).
#include "fracture/fracture_one.h"

namespace fgs {
namespace fracture {

void deform_gaussians_cpu(const DeformInputs& in, const DeformOutputs& out) {
#pragma omp parallel for schedule(static)
  for (int64_t g = 0; g < in.num_gaussians; ++g) deform_one(in, out, g);
}

void lens_ellipsoids_cpu(const LensInputs& in, const LensOutputs& out) {
#pragma omp parallel for schedule(static)
  for (int64_t p = 0; p < in.num_pairs; ++p) lens_one(in, out, p);
}

}  // namespace fracture
}  // namespace fgs
