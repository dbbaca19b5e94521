// model: brittle (fracture_gs/materials/brittle.py; docs/formulas.md, "Brittle damage"): Hencky
// elasticity, no plasticity, Rankine damage with crack-band softening and tension-only degradation.
// State: the damage d in [0, 1] (field 0, never decreasing), the particle's tensile strength
// (Weibull-distributed, set once), and the normal of its crack plane (0 until its damage is
// complete; set and carried with the material by the Python class, read by the fragment partition).
//
// Rankine: the driving stress s is the largest principal value of the undegraded Cauchy stress.
// Crack band: in a band of width h the stress falls linearly from the strength s_F to zero while
// the strain grows to eps_f = 2 G_f / (h s_F), so the band dissipates G_f per unit area; in
// undegraded-stress terms the line ends at s_f = E eps_f = r s_F with r0 = B / s_F^2,
// B = 2 E G_f / (h c_t) (c_t: the share of the uniaxial energy that lies in psi+). Along it the
// stress is g(d) s, hence
//   g_target(s) = s_F (s_f - s) / ((s_f - s_F) s)   for s_F < s < s_f (1 at s_F, 0 at s_f),
// and d follows from g(d) = (1 - d)^2 (1 - k) + k. r = r0 while r0 <= 3; above, the particles beside
// the band soften too (brittle_softening_ratio) and r < r0. A band too coarse for the softening
// (r <= 1) breaks at once. d never decreases: d = max(d_old, d_target(s)), which is d_target of the
// largest s seen so far because d_target is increasing.
#pragma once
#include <cmath>

#include "common/material_law.h"

namespace fgs {

// s_f / s_F of a band whose uniform softening would end at r0 = B / s_F^2 times the strength. The
// quadratic B-spline spreads a velocity jump between two grid nodes over a strain hat two cells
// wide; of four particle layers at the cells' quarter points, the inner pair is strained three times
// as much as the outer pair (for scattered particles this is an approximation).
// In units of c_t s_F^2 / (2E) per unit volume, the inner pair (width h) spends r when it has softened
// to zero; the outer pair (width h), strained to r / 3, softens too once r > 3 and spends
// r (r / 3 - 1) / (r - 1). Asking both together to spend G_f = r0 h (same units) gives
//   4 r^2 - (6 + 3 r0) r + 3 r0 = 0   (r0 > 3; its larger root, 3 at r0 = 3, 3 r0 / 4 for large r0).
HOST_DEVICE FGS_FORCE_INLINE double brittle_softening_ratio(double r0) {
  const double b = 6.0 + 3.0 * r0;
  const double spread = 0.125 * (b + sqrt(b * b - 48.0 * r0));  // b^2 - 48 r0 = 9 (r0 - 2/3)^2 + 32 > 0
  return r0 > 3.0 ? spread : r0;
}

// Degradation g(d) = (1 - d)^2 (1 - k) + k of the tensile part of the energy.
HOST_DEVICE FGS_FORCE_INLINE double brittle_degradation(double d, double residual) {
  return (1.0 - d) * (1.0 - d) * (1.0 - residual) + residual;
}

// Damage the Rankine crack-band law reaches at driving stress s (0 while s <= s_F).
HOST_DEVICE FGS_FORCE_INLINE double brittle_damage_target(double s, double strength, double crack_band,
                                                          double residual) {
  // undegraded stress at which the softening line ends
  const double s_f = strength * brittle_softening_ratio(crack_band / (strength * strength));
  const bool softens = s_f > strength;  // else the band is too coarse: d jumps to 1
  const double span = softens ? (s_f - strength) * s : 1.0;
  const double g_target = softens ? strength * (s_f - s) / span : 0.0;
  double share = (g_target - residual) / (1.0 - residual);  // (1 - d)^2
  share = share > 0.0 ? (share < 1.0 ? share : 1.0) : 0.0;
  return s > strength ? 1.0 - sqrt(share) : 0.0;
}

// psi+ = mu sum <eps_i>+^2 + lambda/2 <e>+^2 of principal strains eps (sum e): the energy damage degrades.
HOST_DEVICE FGS_FORCE_INLINE double brittle_tensile_energy(double mu, double lambda, const double eps[3], double e) {
  double tensile = e > 0.0 ? 0.5 * lambda * e * e : 0.0;
  for (int i = 0; i < 3; ++i) tensile += eps[i] > 0.0 ? mu * eps[i] * eps[i] : 0.0;
  return tensile;
}

struct BrittleModel {
  static constexpr int kCode = 2;
  static constexpr const char* kName = "brittle";
  // strength: the median tensile strength s_F (the state holds each particle's own);
  // crack_band: B = 2 E G_f / (h c_t) (Pa^2), h the crack band width; residual: k, the share of the
  // tensile stiffness left at d = 1.
  static constexpr const char* kParameters[kMatParameters] = {"strength", "crack_band", "residual"};
  enum Parameter : int { kStrength = 0, kCrackBand = 1, kResidual = 2 };
  static constexpr int kStateFields = 5;
  static constexpr const char* kState[kStateFields] = {"damage", "strength", "normal_x", "normal_y", "normal_z"};
  enum State : int { kDamage = 0, kParticleStrength = 1 };

  // F unchanged (no plasticity); the damage grows with the driving stress
  // s = (2 mu dev_max + K e) / J; g(d) degrades the tensile principal stresses.
  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow& m, const float* state,
                                                       const StrainInvariants& s) {
    const double mu = m.mu, K = m.bulk, residual = m.parameter[kResidual];
    const double d_old = state[kDamage], strength = state[kParticleStrength];
    const double driving = (2.0 * mu * s.dev_max + K * s.e) * s.inverse_J;
    const double target = brittle_damage_target(driving, strength, m.parameter[kCrackBand], residual);
    const double damage = target > d_old ? target : d_old;
    LawResult r = elastic_result<kStateFields>(state, s);
    r.state[kDamage] = (float)damage;
    r.shear = brittle_degradation(damage, residual);  // g(d), which principal_stress applies
    // The series path keeps undamaged states below the strength: their stress is the linear one
    // (an upper bound of dev_max gives an upper bound of the driving stress).
    r.decided = (driving < (double)state[kParticleStrength]) & (state[kDamage] == 0.f) ? 1.0 : -1.0;
    return r;
  }

  // Miehe's spectral split: tau_i = 2 mu g_i eps_i + lambda g_e e with g_i = g(d) where eps_i > 0,
  // else 1 (and g_e likewise for e): a crack closed by compression carries the compression, an open
  // one only k of its tension.
  HOST_DEVICE FGS_FORCE_INLINE static double principal_stress(const MaterialRow& m, const LawResult& r, double dev_i,
                                                              double e) {
    const double mu = m.mu, lambda = m.lambda, g = r.shear;
    const double eps_i = dev_i + e * (1.0 / 3.0);
    return 2.0 * mu * (eps_i > 0.0 ? g : 1.0) * eps_i + lambda * (e > 0.0 ? g : 1.0) * e;
  }

  // (g(d_old) - g(d)) psi+: what the elastic energy g psi+ + psi- lost to the damage.
  HOST_DEVICE FGS_FORCE_INLINE static double dissipated(const MaterialRow& m, const float* state, const LawResult& r,
                                                        const double dev[3], double e) {
    const double principal_strain[3] = {dev[0] + e * (1.0 / 3.0), dev[1] + e * (1.0 / 3.0), dev[2] + e * (1.0 / 3.0)};
    return (brittle_degradation(state[kDamage], m.parameter[kResidual]) - r.shear) *
           brittle_tensile_energy(m.mu, m.lambda, principal_strain, e);
  }

  // g(d) psi+ + psi- of the principal strains eps (sum e).
  HOST_DEVICE FGS_FORCE_INLINE static double energy(const MaterialRow& m, const float* state, const double eps[3],
                                                    double e) {
    const double mu = m.mu, lambda = m.lambda;
    double tensile = e > 0.0 ? 0.5 * lambda * e * e : 0.0;
    double compressive = e > 0.0 ? 0.0 : 0.5 * lambda * e * e;
    for (int i = 0; i < 3; ++i) {
      const double part = mu * eps[i] * eps[i];
      tensile += eps[i] > 0.0 ? part : 0.0;
      compressive += eps[i] > 0.0 ? 0.0 : part;
    }
    return brittle_degradation(state[kDamage], m.parameter[kResidual]) * tensile + compressive;
  }
};

}  // namespace fgs
