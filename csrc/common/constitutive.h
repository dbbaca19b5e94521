// The constitutive update through the SVD of F (docs/formulas.md): Hencky strain from the signed
// singular values, the row's law on the strain invariants (csrc/common/material_registry.h), and
// F_E and the Kirchhoff stress composed from the law's answer. It handles every F, inverted ones
// included; the CPU kernels run it for the particles the faster eigen and series paths of
// csrc/common/hencky_eig.h do not take, the CUDA kernels for every particle.
//
// All functions are HOST_DEVICE inline. Interfaces are float32 (row-major float[9] matrices);
// internally everything runs in double (a handful of flops per particle).
//
// The particle state is a block of `stride` floats per particle (csrc/common/material_law.h);
// the update works on a local copy of kMaxStateFields floats (load_state / store_state).
//
// Inverted elements (det F < 0): svd3 returns sigma3 < 0. The Hencky strain uses |sigma|,
// eps_i = ln max(|sigma_i|, 1e-4): an inverted F is treated as its mirror image. Then
// tau = U diag(tau_i) U^T is still (d psi / dF) F^T (because d ln|s| / ds = 1/s), and a law that
// projects returns a positive-determinant F_E = U diag(exp eps') V^T. Where the law keeps F, F is
// returned unchanged, inverted or not.
#pragma once
#include <cmath>
#include <cstdint>

#include "common/hd.h"
#include "common/material_registry.h"
#include "common/svd3.h"

namespace fgs {

constexpr double kMinSingularValue = 1e-4;  // sigma clamp of the Hencky strain

// Particle i's row of a state block (stride floats per particle) as a full local state: the fields
// beyond the stride are zero.
HOST_DEVICE inline void load_state(const float* block, int stride, int64_t i, float state[kMaxStateFields]) {
  for (int k = 0; k < kMaxStateFields; ++k) state[k] = k < stride ? block[stride * i + k] : 0.f;
}

HOST_DEVICE inline void store_state(const float state[kMaxStateFields], int stride, int64_t i, float* block) {
  for (int k = 0; k < stride && k < kMaxStateFields; ++k) block[stride * i + k] = state[k];
}

namespace constitutive_detail {

HOST_DEVICE inline double hencky(double s) {
  const double a = fabs(s);
  return log(a > kMinSingularValue ? a : kMinSingularValue);
}

// R = U diag(d) W^T (double, row-major, singular vectors as columns).
HOST_DEVICE inline void compose(const double U[9], const double d[3], const double W[9], double R[9]) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = U[3 * i] * d[0] * W[3 * j] + U[3 * i + 1] * d[1] * W[3 * j + 1] +
                     U[3 * i + 2] * d[2] * W[3 * j + 2];
}

// Hencky strains eps_i = ln max(|sigma_i|, 1e-4) of the singular values of the float F.
HOST_DEVICE inline void principal_strain(const float F[9], double U[9], double eps[3], double V[9]) {
  double Fd[9], s[3];
  for (int i = 0; i < 9; ++i) Fd[i] = F[i];
  svd3(Fd, U, s, V);
  for (int i = 0; i < 3; ++i) eps[i] = hencky(s[i]);
}

// tau = U diag(d) U^T from principal Kirchhoff stresses d (symmetric: 6 entries computed).
HOST_DEVICE inline void compose_symmetric(const double U[9], const double d[3], float tau[9]) {
  for (int i = 0; i < 3; ++i) {
    const double a0 = U[3 * i] * d[0], a1 = U[3 * i + 1] * d[1], a2 = U[3 * i + 2] * d[2];
    for (int j = i; j < 3; ++j) {
      const float t = static_cast<float>(a0 * U[3 * j] + a1 * U[3 * j + 1] + a2 * U[3 * j + 2]);
      tau[3 * i + j] = t;
      tau[3 * j + i] = t;
    }
  }
}

HOST_DEVICE inline void fill_nan(float F[9], float state[kMaxStateFields], float tau[9]) {
  const float nan = NAN;
  for (int i = 0; i < 9; ++i) {
    F[i] = nan;
    tau[i] = nan;
  }
  state[0] = nan;
}

}  // namespace constitutive_detail

// The update of one particle. mat_row: its material-table row; F: F_trial in, F_E out; state:
// in/out (kMaxStateFields floats); tau: the Kirchhoff stress of F_E; dissipated (may be nullptr):
// the energy per unit rest volume the update took (the law's `dissipated`). A non-finite input or
// an unknown model code gives NaN outputs (the solver's blow-up check reports them).
HOST_DEVICE inline void constitutive_update(const float* mat_row, float F[9], float state[kMaxStateFields],
                                            float tau[9], float* dissipated = nullptr) {
  if (dissipated != nullptr) *dissipated = 0.f;
  // A non-finite input must stay visible: a law's branches could turn a NaN F into a finite
  // projection and hide a blow-up.
  float probe = state[0] * 0.f;
  for (int i = 0; i < 9; ++i) probe += F[i] * 0.f;
  const MaterialRow m = material_row(mat_row);
  if (!(probe == 0.f) || !MaterialModels::known(m)) {
    constitutive_detail::fill_nan(F, state, tau);
    return;
  }
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  const double e = eps[0] + eps[1] + eps[2];
  const double dev[3] = {eps[0] - e / 3.0, eps[1] - e / 3.0, eps[2] - e / 3.0};
  const double dev_max = dev[0] > dev[1] ? (dev[0] > dev[2] ? dev[0] : dev[2]) : (dev[1] > dev[2] ? dev[1] : dev[2]);
  const StrainInvariants s{e, exp(-e), sqrt(dev[0] * dev[0] + dev[1] * dev[1] + dev[2] * dev[2]), dev_max, 0.0};
  const LawResult r = MaterialModels::update(m, state, s);
  if (r.projected > 0.f) {  // F_E = U diag(exp(e_out / 3 + dev_scale dev_i)) V^T
    const double stretch[3] = {exp(r.e_out / 3.0 + r.dev_scale * dev[0]), exp(r.e_out / 3.0 + r.dev_scale * dev[1]),
                               exp(r.e_out / 3.0 + r.dev_scale * dev[2])};
    double R[9];
    constitutive_detail::compose(U, stretch, V, R);
    for (int i = 0; i < 9; ++i) F[i] = static_cast<float>(R[i]);
  }
  const double principal[3] = {MaterialModels::principal_stress(m, r, dev[0], e),
                               MaterialModels::principal_stress(m, r, dev[1], e),
                               MaterialModels::principal_stress(m, r, dev[2], e)};
  constitutive_detail::compose_symmetric(U, principal, tau);
  if (dissipated != nullptr) *dissipated = static_cast<float>(MaterialModels::dissipated(m, state, r, dev, e));
  for (int k = 0; k < kMaxStateFields; ++k) state[k] = r.state[k];
}

// Elastic energy density per unit rest volume psi(F_E) of the row's law at the given state, from
// the principal Hencky strains eps = ln max(|sigma|, 1e-4); NaN for an unknown model.
HOST_DEVICE inline float elastic_energy_density(const float* mat_row, const float F[9],
                                                const float state[kMaxStateFields]) {
  const MaterialRow m = material_row(mat_row);
  if (!MaterialModels::known(m)) return NAN;
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  return static_cast<float>(MaterialModels::energy(m, state, eps, eps[0] + eps[1] + eps[2]));
}

// Particle i of a batch: copy in, update, copy out (outputs may alias inputs). An out-of-range
// material id gives NaN outputs; returns whether the id was valid. dissipated may be nullptr.
// Used by the CPU and CUDA ops.
HOST_DEVICE inline bool constitutive_update_particle(int64_t i, const float* F_trial, const float* state_in,
                                                     int stride, const float* material_table, int64_t n_materials,
                                                     const int32_t* material_id, float* F_out, float* state_out,
                                                     float* tau_out, float* dissipated) {
  float F[9], tau[9], state[kMaxStateFields], taken = 0.f;
  for (int k = 0; k < 9; ++k) F[k] = F_trial[9 * i + k];
  load_state(state_in, stride, i, state);
  const int32_t id = material_id[i];
  const bool valid = id >= 0 && id < n_materials;
  if (valid) {
    constitutive_update(material_table + kMatFields * static_cast<int64_t>(id), F, state, tau, &taken);
  } else {
    constitutive_detail::fill_nan(F, state, tau);
  }
  for (int k = 0; k < 9; ++k) {
    F_out[9 * i + k] = F[k];
    tau_out[9 * i + k] = tau[k];
  }
  store_state(state, stride, i, state_out);
  if (dissipated != nullptr) dissipated[i] = taken;
  return valid;
}

}  // namespace fgs
