// Split directions carried with the material: a unit normal per particle, held in three fields of
// its material state (0 0 0: none yet), that starts when a trigger field of the state reaches a
// value and then turns with the material like the normal of a material plane (a crack plane). The
// torch twin is fracture_gs/materials/split_directions.py; CPU and CUDA loops call this per particle.
#pragma once
#include <cmath>

#include "hd.h"
#include "svd3.h"

namespace fgs {

struct SplitDirectionParams {
  int first;              // state column of the normal's x component (y and z follow)
  int trigger;            // state column whose value starts the normal
  float start;            // the trigger value from which a particle has a normal
  float dt;               // the substep
  float orientation[3];   // normals point to this side: n . orientation > 0
};

// One particle after its substep. state: its material state row (changed in place); trigger_old: the
// trigger field before the substep; C, F_E: its APIC matrix and deformation gradient after the substep
// (row-major 3x3).
//   Has a normal: n <- (I - dt C^T) n, normalised (the normal of a material plane under the
//   velocity gradient C).
//   No normal yet and the trigger grew to >= start in this substep: n = the direction of the largest
//   principal stretch of F_E (first left singular vector), oriented.
HOST_DEVICE inline void split_direction_step(float* state, float trigger_old, const float C[9], const float F_E[9],
                                             const SplitDirectionParams& p) {
  float* n = state + p.first;
  if (n[0] != 0.f || n[1] != 0.f || n[2] != 0.f) {
    float m[3];
    for (int i = 0; i < 3; ++i) m[i] = n[i] - p.dt * (C[i] * n[0] + C[3 + i] * n[1] + C[6 + i] * n[2]);
    const float norm = sqrtf(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    for (int i = 0; i < 3; ++i) n[i] = m[i] / norm;
    return;
  }
  const float value = state[p.trigger];
  if (!(value > trigger_old && value >= p.start)) return;
  double F[9], U[9], sigma[3], V[9];
  for (int i = 0; i < 9; ++i) F[i] = static_cast<double>(F_E[i]);
  svd3(F, U, sigma, V);
  const double u[3] = {U[0], U[3], U[6]};
  const double along = u[0] * p.orientation[0] + u[1] * p.orientation[1] + u[2] * p.orientation[2];
  const double sign = along < 0.0 ? -1.0 : 1.0;
  for (int i = 0; i < 3; ++i) n[i] = static_cast<float>(sign * u[i]);
}

}  // namespace fgs
