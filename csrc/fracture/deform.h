// Gaussians that follow particles (docs/formulas.md §12), one Gaussian at a time; shared by the CPU and
// CUDA kernels of fracture_kernels.h.
//
// A Gaussian driven by particle p with elastic deformation gradient F = F_E[p]:
//   mean       = x_p + F · offset0          (offset0: rest offset of the Gaussian from p)
//   covariance = F Σ0 Fᵀ
//   view rotation = R_F · R_obj, R_F the polar rotation of F (det +1: U Vᵀ of the signed SVD),
//     R_obj the rotation of the object's scene transform: the SH are stored in the model frame,
//     so a world view direction d is looked up at (R_F R_obj)ᵀ d.
#pragma once
#include "common/hd.h"
#include "common/svd3.h"

namespace fgs {
namespace fracture {

HOST_DEVICE inline void polar_rotation(const float F[9], double R[9]) {
  double Fd[9], U[9], sigma[3], V[9];
  for (int i = 0; i < 9; ++i) Fd[i] = static_cast<double>(F[i]);
  svd3(Fd, U, sigma, V);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      R[3 * r + c] = U[3 * r] * V[3 * c] + U[3 * r + 1] * V[3 * c + 1] + U[3 * r + 2] * V[3 * c + 2];
}

// One Gaussian; all matrices row-major float[9].
HOST_DEVICE inline void deform_gaussian(const float x[3], const float F[9], const float offset[3],
                                        const float cov0[9], const float object_rotation[9],
                                        float mean[3], float cov[9], float view_rotation[9]) {
  for (int r = 0; r < 3; ++r)
    mean[r] = x[r] + F[3 * r] * offset[0] + F[3 * r + 1] * offset[1] + F[3 * r + 2] * offset[2];
  double FS[9];  // F Σ0, then F Σ0 Fᵀ in double (keeps the result symmetric to float precision)
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      FS[3 * r + c] = (double)F[3 * r] * cov0[c] + (double)F[3 * r + 1] * cov0[3 + c] +
                      (double)F[3 * r + 2] * cov0[6 + c];
  for (int r = 0; r < 3; ++r)
    for (int c = r; c < 3; ++c) {
      const double v = FS[3 * r] * F[3 * c] + FS[3 * r + 1] * F[3 * c + 1] + FS[3 * r + 2] * F[3 * c + 2];
      cov[3 * r + c] = cov[3 * c + r] = static_cast<float>(v);
    }
  double R[9];
  polar_rotation(F, R);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      view_rotation[3 * r + c] = static_cast<float>(R[3 * r] * object_rotation[c] +
                                                    R[3 * r + 1] * object_rotation[3 + c] +
                                                    R[3 * r + 2] * object_rotation[6 + c]);
}

}  // namespace fracture
}  // namespace fgs
