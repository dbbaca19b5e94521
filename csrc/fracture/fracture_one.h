// One row of each fracture kernel, shared by fracture_cpu.cpp and fracture_cuda.cu.
#pragma once
#include "common/mvee.h"
#include "fracture/deform.h"
#include "fracture/fracture_kernels.h"

namespace fgs {
namespace fracture {

HOST_DEVICE inline void deform_one(const DeformInputs& in, const DeformOutputs& out, int64_t g) {
  const int64_t p = in.driver[g];
  deform_gaussian(in.x + 3 * p, in.F + 9 * p, in.rest_offset + 3 * g, in.rest_covariance + 9 * g,
                  in.object_rotation + 9 * (int64_t)in.gaussian_object[g], out.means + 3 * g,
                  out.covariances + 9 * g, out.view_rotations + 9 * g);
}

HOST_DEVICE inline void lens_one(const LensInputs& in, const LensOutputs& out, int64_t p) {
  const mvee::Lens lens = mvee::lens_ellipsoid(in.centre_i + 3 * p, in.radius_i[p],
                                               in.centre_j + 3 * p, in.radius_j[p], in.k_sigma);
  for (int a = 0; a < 3; ++a) {
    out.centre[3 * p + a] = lens.centre[a];
    out.scales[3 * p + a] = lens.scales[a];
  }
  for (int a = 0; a < 9; ++a) {
    out.rotation[9 * p + a] = lens.rotation[a];
    out.covariance[9 * p + a] = lens.covariance[a];
  }
  out.valid[p] = lens.valid;
}

}  // namespace fracture
}  // namespace fgs
