// Constitutive models of the MPM solver (SPEC §5.3): St. Venant-Kirchhoff elasticity on the
// Hencky strain, and the NACC return map (Wolper et al. 2019) with CD-MPM hardening.
//
// All functions are HOST_DEVICE inline and shared by the OpenMP and CUDA kernels. Interfaces
// are float32 (row-major float[9] matrices); internally everything runs in double (a handful
// of flops per particle), so the float results are the correctly rounded double results.
//
// Material table row (float[8], see MatField and docs/design_mpm.md):
//   model (0 elastic, 1 nacc), mu, lambda, bulk K, beta, xi, M, alpha_threshold.
//
// Inverted elements (det F < 0): svd3 returns sigma3 < 0. The Hencky strain uses |sigma|,
// eps_i = ln max(|sigma_i|, 1e-4): an inverted F is treated as its mirror image. Then
// tau = U diag(2 mu eps + lambda tr eps) U^T is still exactly (d psi / dF) F^T (because
// d ln|s| / ds = 1/s), and the NACC return map, when it projects, returns a positive-determinant
// F_E = U diag(exp eps') V^T. Inside the yield surface (and for the elastic model) F is returned
// unchanged, inverted or not.
#pragma once
#include <cmath>
#include <cstdint>

#include "common/hd.h"
#include "common/svd3.h"

namespace fgs {

// Columns of one material-table row.
enum MatField : int {
  kMatModel = 0,           // 0 = elastic, 1 = nacc
  kMatMu = 1,              // Lame mu
  kMatLambda = 2,          // Lame lambda
  kMatBulk = 3,            // K = lambda + 2 mu / 3
  kMatBeta = 4,            // NACC beta (tension/compression asymmetry)
  kMatXi = 5,              // NACC xi (hardening)
  kMatM = 6,               // NACC M (slope of the critical state line)
  kMatAlphaThreshold = 7,  // fracture flag: fractured once alpha >= this (used by the solver)
  kMatFields = 8
};

enum MaterialModel : int { kModelElastic = 0, kModelNacc = 1 };

constexpr double kMinSingularValue = 1e-4;  // sigma clamp of the Hencky strain
constexpr double kNaccP0Floor = 1e-5;       // p0 = K (1e-5 + sinh(xi max(-alpha, 0)))
// y > kNaccYieldTol (M p0)^2 triggers the projection: relative to the ellipse's own size, so a
// particle with p0 at its floor 1e-5 K is still projected and hardened. (SPEC 5.3 wrote 1e-8 K^2
// and gated hardening on p0 > 1e-4 K: both absolute, and material failing in shear then stopped
// at alpha ~ -9e-5 / xi, short of the fracture threshold 0. ziran gates on 1e-4 Pa, which is
// below our floor for any K > 10 Pa.) Hardening is gated relative to p0 only: -beta p0 < p < p0.
constexpr double kNaccYieldTol = 1e-6;

// The yield tolerance of a state with cohesion p0 and critical-state slope M.
HOST_DEVICE inline double nacc_yield_tolerance(double p0, double M) { return kNaccYieldTol * (M * p0) * (M * p0); }

namespace constitutive_detail {

HOST_DEVICE inline double hencky(double s) {
  const double a = fabs(s);
  return log(a > kMinSingularValue ? a : kMinSingularValue);
}

// sinh(x) for x > 0 from one exp (~1e-16 (1 + sinh x) absolute error: all that p0 needs, as it
// adds a 1e-5 floor), about half the cost of sinh().
HOST_DEVICE inline double sinh_nonnegative(double x) {
  const double e = exp(x);
  return 0.5 * (e - 1.0 / e);
}

// R = U diag(d) W^T (double, row-major, singular vectors as columns).
HOST_DEVICE inline void compose(const double U[9], const double d[3], const double W[9], double R[9]) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = U[3 * i] * d[0] * W[3 * j] + U[3 * i + 1] * d[1] * W[3 * j + 1] +
                     U[3 * i + 2] * d[2] * W[3 * j + 2];
}

// tau = U diag(2 mu eps + lambda (sum eps)) U^T (symmetric: 6 entries computed).
HOST_DEVICE inline void kirchhoff_from_strain(double mu, double lambda, const double U[9],
                                              const double eps[3], float tau[9]) {
  const double tr = eps[0] + eps[1] + eps[2];
  const double d0 = 2.0 * mu * eps[0] + lambda * tr, d1 = 2.0 * mu * eps[1] + lambda * tr,
               d2 = 2.0 * mu * eps[2] + lambda * tr;
  for (int i = 0; i < 3; ++i) {
    const double a0 = U[3 * i] * d0, a1 = U[3 * i + 1] * d1, a2 = U[3 * i + 2] * d2;
    for (int j = i; j < 3; ++j) {
      const float t = static_cast<float>(a0 * U[3 * j] + a1 * U[3 * j + 1] + a2 * U[3 * j + 2]);
      tau[3 * i + j] = t;
      tau[3 * j + i] = t;
    }
  }
}

// Hencky strains eps_i = ln max(|sigma_i|, 1e-4) of the singular values of the float F.
HOST_DEVICE inline void principal_strain(const float F[9], double U[9], double eps[3], double V[9]) {
  double Fd[9], s[3];
  for (int i = 0; i < 9; ++i) Fd[i] = F[i];
  svd3(Fd, U, s, V);
  for (int i = 0; i < 3; ++i) eps[i] = hencky(s[i]);
}

HOST_DEVICE inline void fill_nan(float F[9], float* alpha, float tau[9]) {
  const float nan = NAN;
  for (int i = 0; i < 9; ++i) {
    F[i] = nan;
    tau[i] = nan;
  }
  *alpha = nan;
}

}  // namespace constitutive_detail

// Kirchhoff stress of the Hencky StVK model for F = U diag(sigma) V^T (U, sigma from svd3):
// tau = U diag(2 mu eps + lambda tr(eps)) U^T, eps = ln max(|sigma|, 1e-4).
HOST_DEVICE inline void hencky_kirchhoff(float mu, float lambda, const float U[9],
                                         const float sigma[3], float tau[9]) {
  double Ud[9];
  for (int i = 0; i < 9; ++i) Ud[i] = U[i];
  const double eps[3] = {constitutive_detail::hencky(sigma[0]), constitutive_detail::hencky(sigma[1]),
                         constitutive_detail::hencky(sigma[2])};
  constitutive_detail::kirchhoff_from_strain(mu, lambda, Ud, eps, tau);
}

// Kirchhoff stress tau(F) of the Hencky StVK model with the mu, lambda of a table row
// (any model: the elasticity is the same).
HOST_DEVICE inline void kirchhoff_stress(const float* mat_row, const float F[9], float tau[9]) {
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  constitutive_detail::kirchhoff_from_strain(mat_row[kMatMu], mat_row[kMatLambda], U, eps, tau);
}

// Elastic model: F and alpha unchanged, tau = tau(F).
HOST_DEVICE inline void elastic_update(const float* mat_row, float F[9], float* alpha, float tau[9]) {
  (void)alpha;
  kirchhoff_stress(mat_row, F, tau);
}

// NACC return map (SPEC §5.3). On entry F = F_trial, on exit F = F_E; alpha updated;
// tau = Kirchhoff stress of F_E.
HOST_DEVICE inline void nacc_update(const float* mat_row, float F[9], float* alpha, float tau[9]) {
  using constitutive_detail::hencky;
  const double mu = mat_row[kMatMu], lambda = mat_row[kMatLambda], K = mat_row[kMatBulk];
  const double beta = mat_row[kMatBeta], xi = mat_row[kMatXi], M = mat_row[kMatM];
  double a = *alpha;

  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  const double e = eps[0] + eps[1] + eps[2];
  const double dev[3] = {eps[0] - e / 3.0, eps[1] - e / 3.0, eps[2] - e / 3.0};
  const double dev_norm = sqrt(dev[0] * dev[0] + dev[1] * dev[1] + dev[2] * dev[2]);

  const double softened = (-a > 0.0) ? -a : 0.0;  // max(-alpha, 0)
  const double p0 = K * (kNaccP0Floor + (softened > 0.0 ? constitutive_detail::sinh_nonnegative(xi * softened) : 0.0));
  const double p = -K * e;
  const double q = sqrt(1.5) * 2.0 * mu * dev_norm;

  double eps_new[3];
  bool projected = true;
  bool tip = false;
  if (p > p0) {  // compression tip
    const double e_new = -p0 / K;
    for (int i = 0; i < 3; ++i) eps_new[i] = e_new / 3.0;
    a += e - e_new;
    tip = true;
  } else if (p < -beta * p0) {  // tension tip: cohesion lost
    const double e_new = beta * p0 / K;
    for (int i = 0; i < 3; ++i) eps_new[i] = e_new / 3.0;
    a += e - e_new;
    tip = true;
  } else {
    const double y = (1.0 + 2.0 * beta) * q * q + M * M * (p + beta * p0) * (p - p0);
    if (y > nacc_yield_tolerance(p0, M)) {
      // Here (p + beta p0)(p0 - p) >= 0, so y > 0 implies q > 0; the guard is belt and braces.
      const double q_new = M * sqrt((p + beta * p0) * (p0 - p) / (1.0 + 2.0 * beta));
      const double scale = (q > 0.0) ? q_new / q : 0.0;
      for (int i = 0; i < 3; ++i) eps_new[i] = e / 3.0 + scale * dev[i];  // volume preserving
      if (-beta * p0 < p && p < p0) {
        // CD-MPM hardening: move alpha as if p went toward the ellipse centre along the ray.
        const double pc = 0.5 * (1.0 - beta) * p0;
        const double half_axis = 0.5 * (1.0 + beta) * p0;
        const double t = M * half_axis / sqrt((1.0 + 2.0 * beta) * q * q + M * M * (p - pc) * (p - pc));
        const double p_final = pc + t * (p - pc);
        a += (p_final - p) / K;
      }
    } else {
      projected = false;  // inside the yield surface: F unchanged
    }
  }

  if (projected) {
    const double d0 = exp(eps_new[0]);  // tips: all three equal, one exp
    const double d[3] = {d0, tip ? d0 : exp(eps_new[1]), tip ? d0 : exp(eps_new[2])};
    double R[9];
    constitutive_detail::compose(U, d, V, R);
    for (int i = 0; i < 9; ++i) F[i] = static_cast<float>(R[i]);
    *alpha = static_cast<float>(a);
    constitutive_detail::kirchhoff_from_strain(mu, lambda, U, eps_new, tau);
  } else {
    constitutive_detail::kirchhoff_from_strain(mu, lambda, U, eps, tau);
  }
}

// Dispatch on the model column. F: F_trial in, F_E out; alpha: in/out; tau: Kirchhoff stress.
// An unknown model code gives NaN outputs (the solver's blow-up check reports it).
HOST_DEVICE inline void constitutive_update(const float* mat_row, float F[9], float* alpha, float tau[9]) {
  // A non-finite input must stay visible: the return map's branches would otherwise turn a NaN
  // F into a finite tip projection and hide a blow-up.
  float probe = *alpha * 0.f;
  for (int i = 0; i < 9; ++i) probe += F[i] * 0.f;
  if (!(probe == 0.f)) {
    constitutive_detail::fill_nan(F, alpha, tau);
    return;
  }
  const int model = static_cast<int>(mat_row[kMatModel]);
  if (model == kModelElastic) {
    elastic_update(mat_row, F, alpha, tau);
  } else if (model == kModelNacc) {
    nacc_update(mat_row, F, alpha, tau);
  } else {
    constitutive_detail::fill_nan(F, alpha, tau);
  }
}

// Elastic energy density per unit rest volume: psi = mu |eps|^2 + lambda/2 (tr eps)^2,
// eps = ln max(|sigma|, 1e-4) (same for every model).
HOST_DEVICE inline float elastic_energy_density(const float* mat_row, const float F[9]) {
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  const double tr = eps[0] + eps[1] + eps[2];
  const double mu = mat_row[kMatMu], lambda = mat_row[kMatLambda];
  return static_cast<float>(mu * (eps[0] * eps[0] + eps[1] * eps[1] + eps[2] * eps[2]) +
                            0.5 * lambda * tr * tr);
}

// Particle i of a batch: copy in, update, copy out (outputs may alias inputs). An out-of-range
// material id gives NaN outputs; returns whether the id was valid. Used by the CPU and CUDA ops.
HOST_DEVICE inline bool constitutive_update_particle(int64_t i, const float* F_trial, const float* alpha_in,
                                                     const float* material_table, int64_t n_materials,
                                                     const int32_t* material_id, float* F_out, float* alpha_out,
                                                     float* tau_out) {
  float F[9], tau[9];
  for (int k = 0; k < 9; ++k) F[k] = F_trial[9 * i + k];
  float alpha = alpha_in[i];
  const int32_t id = material_id[i];
  const bool valid = id >= 0 && id < n_materials;
  if (valid) {
    constitutive_update(material_table + kMatFields * static_cast<int64_t>(id), F, &alpha, tau);
  } else {
    constitutive_detail::fill_nan(F, &alpha, tau);
  }
  for (int k = 0; k < 9; ++k) {
    F_out[9 * i + k] = F[k];
    tau_out[9 * i + k] = tau[k];
  }
  alpha_out[i] = alpha;
  return valid;
}

}  // namespace fgs
