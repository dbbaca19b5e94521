// Constitutive models of the MPM solver (docs/formulas.md): St. Venant-Kirchhoff elasticity on the
// Hencky strain, the NACC return map (Wolper et al. 2019) with CD-MPM hardening, and the brittle
// damage model (Rankine driving stress, crack-band softening, tension-only degradation).
//
// All functions are HOST_DEVICE inline and shared by the OpenMP and CUDA kernels. Interfaces
// are float32 (row-major float[9] matrices); internally everything runs in double (a handful
// of flops per particle), so the float results are the correctly rounded double results.
//
// Material table row (float[8], see MatField and docs/design_mpm.md):
//   model (0 elastic, 1 nacc, 2 brittle), mu, lambda, bulk K, three model parameters
//   (nacc: beta, xi, M; brittle: strength, crack band constant, residual), fracture threshold.
//
// The per-particle scalar state `alpha` is the model's internal variable: NACC's hardening state
// alpha, the brittle damage d in [0, 1], unused (constant) for the elastic model.
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
  kMatModel = 0,              // 0 = elastic, 1 = nacc, 2 = brittle
  kMatMu = 1,                 // Lame mu
  kMatLambda = 2,             // Lame lambda
  kMatBulk = 3,               // K = lambda + 2 mu / 3
  kMatBeta = 4,               // NACC beta (tension/compression asymmetry)
  kMatXi = 5,                 // NACC xi (hardening)
  kMatM = 6,                  // NACC M (slope of the critical state line)
  kMatStrength = 4,           // brittle: tensile strength sigma_F (median; per-particle values override it)
  kMatCrackBand = 5,          // brittle: B = 2 E G_f / (h c_t) (Pa^2), h the crack band width
  kMatResidual = 6,           // brittle: k, share of the tensile stiffness left at d = 1
  kMatFractureThreshold = 7,  // fracture flag: fractured once alpha (nacc) or d (brittle) >= this
  kMatFields = 8
};

enum MaterialModel : int { kModelElastic = 0, kModelNacc = 1, kModelBrittle = 2 };

constexpr double kMinSingularValue = 1e-4;  // sigma clamp of the Hencky strain
constexpr double kNaccP0Floor = 1e-5;       // p0 = K (1e-5 + sinh(xi max(-alpha, 0)))
// y > kNaccYieldTol (M p0)^2 triggers the projection: relative to the ellipse's own size, so a
// particle with p0 at its floor 1e-5 K is still projected and hardened. (An absolute 1e-8 K^2
// with hardening gated on p0 > 1e-4 K would stop material failing in shear
// at alpha ~ -9e-5 / xi, short of the fracture threshold 0. ziran gates on 1e-4 Pa, which is
// below our floor for any K > 10 Pa.) Hardening is gated relative to p0 only: -beta p0 < p < p0.
constexpr double kNaccYieldTol = 1e-6;

// The yield tolerance of a state with cohesion p0 and critical-state slope M.
HOST_DEVICE inline double nacc_yield_tolerance(double p0, double M) { return kNaccYieldTol * (M * p0) * (M * p0); }

// ---------------------------------------------------------------------------------------------
// Brittle damage (docs/formulas.md, "Brittle damage"). Rankine: the driving stress s is the largest
// principal value of the undegraded Cauchy stress. Crack band: in a band of width h the stress
// falls linearly from the strength s_F to zero while the strain grows to eps_f = 2 G_f / (h s_F), so
// the band dissipates G_f per unit area; in undegraded-stress terms the line ends at
// s_f = E eps_f = r s_F with r0 = B / s_F^2, B = 2 E G_f / (h c_t) (c_t: the share of the uniaxial
// energy that lies in psi+). Along it the stress is g(d) s, hence
//   g_target(s) = s_F (s_f - s) / ((s_f - s_F) s)   for s_F < s < s_f (1 at s_F, 0 at s_f),
// and d follows from g(d) = (1 - d)^2 (1 - k) + k. r = r0 while r0 <= 3; above, the particles beside
// the band soften too (brittle_softening_ratio) and r < r0. A band too coarse for the softening
// (r <= 1) breaks at once. d never decreases: d = max(d_old, d_target(s)), which is d_target of the
// largest s seen so far because d_target is increasing. Written with selects only (the CPU tiers
// vectorise it).

// s_f / s_F of a band whose uniform softening would end at r0 = B / s_F^2 times the strength. The
// quadratic B-spline spreads a velocity jump between two grid nodes over a strain hat two cells
// wide; of four particle layers at the cells' quarter points, the inner pair is strained three times
// as much as the outer pair (for scattered particles this is an approximation).
// In units of c_t s_F^2 / (2E) per unit volume, the inner pair (width h) spends r when it has softened
// to zero; the outer pair (width h), strained to r / 3, softens too once r > 3 and spends
// r (r / 3 - 1) / (r - 1). Asking both together to spend G_f = r0 h (same units) gives
//   4 r^2 - (6 + 3 r0) r + 3 r0 = 0   (r0 > 3; its larger root, 3 at r0 = 3, 3 r0 / 4 for large r0).
HOST_DEVICE inline double brittle_softening_ratio(double r0) {
  const double b = 6.0 + 3.0 * r0;
  const double spread = 0.125 * (b + sqrt(b * b - 48.0 * r0));  // b^2 - 48 r0 = 9 (r0 - 2/3)^2 + 32 > 0
  return r0 > 3.0 ? spread : r0;
}

// Degradation g(d) = (1 - d)^2 (1 - k) + k of the tensile part of the energy.
HOST_DEVICE inline double brittle_degradation(double d, double residual) {
  return (1.0 - d) * (1.0 - d) * (1.0 - residual) + residual;
}

// Damage the Rankine crack-band law reaches at driving stress s (0 while s <= s_F).
HOST_DEVICE inline double brittle_damage_target(double s, double strength, double crack_band, double residual) {
  // undegraded stress at which the softening line ends
  const double s_f = strength * brittle_softening_ratio(crack_band / (strength * strength));
  const bool softens = s_f > strength;  // else the band is too coarse: d jumps to 1
  const double span = softens ? (s_f - strength) * s : 1.0;
  const double g_target = softens ? strength * (s_f - s) / span : 0.0;
  double share = (g_target - residual) / (1.0 - residual);  // (1 - d)^2
  share = share > 0.0 ? (share < 1.0 ? share : 1.0) : 0.0;
  return s > strength ? 1.0 - sqrt(share) : 0.0;
}

// What the brittle model does to a state with volumetric Hencky strain e = ln J, largest principal
// deviatoric strain dev_max and old damage d_old: the new damage and its degradation g(d).
struct BrittleResponse {
  double damage;   // new d
  double driving;  // undegraded largest principal Cauchy stress
  double g;        // g(d)
};

// inverse_J = 1 / det F (the Cauchy stress is tau / J), passed in so that vectorised callers need no exp.
HOST_DEVICE inline BrittleResponse brittle_response(double mu, double K, double strength, double crack_band,
                                                    double residual, double d_old, double e, double inverse_J,
                                                    double dev_max) {
  BrittleResponse r;
  r.driving = (2.0 * mu * dev_max + K * e) * inverse_J;
  const double target = brittle_damage_target(r.driving, strength, crack_band, residual);
  r.damage = target > d_old ? target : d_old;
  r.g = brittle_degradation(r.damage, residual);
  return r;
}

// Principal Kirchhoff stress of the brittle model (Miehe's spectral split: the tensile part of the
// energy, psi+ = mu sum <eps_i>+^2 + lambda/2 <e>+^2, is degraded by g, the compressive part never):
// tau_i = 2 mu g_i eps_i + lambda g_e e with g_i = g where eps_i > 0, else 1 (and g_e likewise for e).
// A crack closed by compression carries the compression; an open one carries only k of its tension.
HOST_DEVICE inline double brittle_principal_stress(double mu, double lambda, double g, double eps_i, double e) {
  return 2.0 * mu * (eps_i > 0.0 ? g : 1.0) * eps_i + lambda * (e > 0.0 ? g : 1.0) * e;
}

// Elastic energy density of the brittle model: g(d) psi+ + psi- of the principal strains eps (sum e).
HOST_DEVICE inline double brittle_energy_density(double mu, double lambda, double residual, double d,
                                                 const double eps[3], double e) {
  double tensile = e > 0.0 ? 0.5 * lambda * e * e : 0.0;
  double compressive = e > 0.0 ? 0.0 : 0.5 * lambda * e * e;
  for (int i = 0; i < 3; ++i) {
    const double part = mu * eps[i] * eps[i];
    tensile += eps[i] > 0.0 ? part : 0.0;
    compressive += eps[i] > 0.0 ? 0.0 : part;
  }
  return brittle_degradation(d, residual) * tensile + compressive;
}

// psi+ = mu sum <eps_i>+^2 + lambda/2 <e>+^2 of principal strains eps (sum e): the energy damage degrades.
HOST_DEVICE inline double brittle_tensile_energy(double mu, double lambda, const double eps[3], double e) {
  double tensile = e > 0.0 ? 0.5 * lambda * e * e : 0.0;
  for (int i = 0; i < 3; ++i) tensile += eps[i] > 0.0 ? mu * eps[i] * eps[i] : 0.0;
  return tensile;
}

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

// NACC return map (docs/formulas.md §4). On entry F = F_trial, on exit F = F_E; alpha updated;
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

// Brittle model: F unchanged (no plasticity), alpha = damage d updated, tau = degraded stress of F.
// strength: the particle's tensile strength (Weibull-distributed per particle, or the row's);
// dissipated (may be nullptr): the energy per unit rest volume the damage took, (g(d_old) - g(d)) psi+.
HOST_DEVICE inline void brittle_update(const float* mat_row, float strength, float F[9], float* alpha, float tau[9],
                                       float* dissipated) {
  const double mu = mat_row[kMatMu], lambda = mat_row[kMatLambda], K = mat_row[kMatBulk];
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  const double e = eps[0] + eps[1] + eps[2];
  const double eps_max = eps[0] > eps[1] ? (eps[0] > eps[2] ? eps[0] : eps[2]) : (eps[1] > eps[2] ? eps[1] : eps[2]);
  const BrittleResponse r = brittle_response(mu, K, strength, mat_row[kMatCrackBand], mat_row[kMatResidual],
                                             *alpha, e, exp(-e), eps_max - e / 3.0);
  const double principal[3] = {brittle_principal_stress(mu, lambda, r.g, eps[0], e),
                               brittle_principal_stress(mu, lambda, r.g, eps[1], e),
                               brittle_principal_stress(mu, lambda, r.g, eps[2], e)};
  constitutive_detail::compose_symmetric(U, principal, tau);
  if (dissipated != nullptr)
    *dissipated = static_cast<float>((brittle_degradation(*alpha, mat_row[kMatResidual]) - r.g) *
                                     brittle_tensile_energy(mu, lambda, eps, e));
  *alpha = static_cast<float>(r.damage);
}

// Dispatch on the model column. F: F_trial in, F_E out; alpha: in/out; tau: Kirchhoff stress;
// strength: the particle's tensile strength (read by the brittle model only); dissipated (may be
// nullptr): the energy per unit rest volume the brittle damage took (0 for the other models).
// An unknown model code gives NaN outputs (the solver's blow-up check reports it).
HOST_DEVICE inline void constitutive_update(const float* mat_row, float F[9], float* alpha, float tau[9],
                                            float strength, float* dissipated = nullptr) {
  if (dissipated != nullptr) *dissipated = 0.f;
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
  } else if (model == kModelBrittle) {
    brittle_update(mat_row, strength, F, alpha, tau, dissipated);
  } else {
    constitutive_detail::fill_nan(F, alpha, tau);
  }
}

// Elastic energy density per unit rest volume: psi = mu |eps|^2 + lambda/2 (tr eps)^2,
// eps = ln max(|sigma|, 1e-4); the brittle model degrades its tensile part by g(d), d = alpha.
HOST_DEVICE inline float elastic_energy_density(const float* mat_row, const float F[9], float alpha) {
  double U[9], eps[3], V[9];
  constitutive_detail::principal_strain(F, U, eps, V);
  const double tr = eps[0] + eps[1] + eps[2];
  const double mu = mat_row[kMatMu], lambda = mat_row[kMatLambda];
  if (static_cast<int>(mat_row[kMatModel]) == kModelBrittle)
    return static_cast<float>(brittle_energy_density(mu, lambda, mat_row[kMatResidual], alpha, eps, tr));
  return static_cast<float>(mu * (eps[0] * eps[0] + eps[1] * eps[1] + eps[2] * eps[2]) +
                            0.5 * lambda * tr * tr);
}

// Tensile strength of a particle: its own (strength, may be nullptr) or its material row's.
HOST_DEVICE inline float particle_strength(const float* strength, int64_t i, const float* mat_row) {
  return strength != nullptr ? strength[i] : mat_row[kMatStrength];
}

// Particle i of a batch: copy in, update, copy out (outputs may alias inputs). An out-of-range
// material id gives NaN outputs; returns whether the id was valid. Used by the CPU and CUDA ops.
HOST_DEVICE inline bool constitutive_update_particle(int64_t i, const float* F_trial, const float* alpha_in,
                                                     const float* strength, const float* material_table,
                                                     int64_t n_materials, const int32_t* material_id, float* F_out,
                                                     float* alpha_out, float* tau_out) {
  float F[9], tau[9];
  for (int k = 0; k < 9; ++k) F[k] = F_trial[9 * i + k];
  float alpha = alpha_in[i];
  const int32_t id = material_id[i];
  const bool valid = id >= 0 && id < n_materials;
  if (valid) {
    const float* row = material_table + kMatFields * static_cast<int64_t>(id);
    constitutive_update(row, F, &alpha, tau, particle_strength(strength, i, row));
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
