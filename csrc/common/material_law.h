// What every material model provides, and the layout of the material table and of the particle
// state. The models themselves live in csrc/common/materials/ (one header each, its law written
// once); csrc/common/material_registry.h lists them and dispatches on a row's model code. The
// generic update paths (the SVD path of csrc/common/constitutive.h, the eigen and series paths of
// csrc/common/hencky_eig.h) compute the strain, hand its invariants to the model, and compose the
// model's answer back into F_E and tau: none of them knows a model by name.
//
// A model is a struct with:
//   kCode, kName                      its code in the table's model column and its YAML name
//   kParameters[kMatParameters]       names of its parameter columns ("" where unused)
//   kStateFields, kState[]            its per-particle state: field 0 is the variable the fracture
//                                     threshold applies to; the others are the model's own
//   update(row, state, invariants)    its law on the strain invariants -> LawResult
//   principal_stress(row, result, dev_i, e)          principal Kirchhoff stress tau_i
//   dissipated(row, state, result, dev, e)           energy per unit rest volume the update took
//   energy(row, state, eps, e)                       elastic energy density psi
// (the last three inherited from HenckyLaw below where they are the Hencky ones)
// All of them HOST_DEVICE FGS_FORCE_INLINE (the CPU paths vectorise over particles, so a law is
// written with selects rather than branches).
#pragma once
#include <cstdint>

#include "common/hd.h"

namespace fgs {

// Columns of a material-table row (float[kMatFields]). Columns kMatParameter ..
// kMatParameter + kMatParameters - 1 belong to the row's model, which names them (kParameters).
enum MatField : int {
  kMatModel = 0,              // the model's kCode
  kMatMu = 1,                 // Lame mu
  kMatLambda = 2,             // Lame lambda
  kMatBulk = 3,               // K = lambda + 2 mu / 3
  kMatParameter = 4,          // the model's first parameter
  kMatFractureThreshold = 7,  // a particle counts as fractured once its state field 0 reaches this
  kMatFields = 8
};
constexpr int kMatParameters = kMatFractureThreshold - kMatParameter;

// Per-particle state: a block of `stride` floats per particle, stride = the largest kStateFields
// of the scene's models. A particle's model owns fields [0, kStateFields); the rest of its row
// stays as it was (zero). No model may have more than kStateCapacity fields.
constexpr int kStateCapacity = 8;

// A material-table row as the laws read it.
struct MaterialRow {
  float model, mu, lambda, bulk;
  float parameter[kMatParameters];
};

HOST_DEVICE FGS_FORCE_INLINE MaterialRow material_row(const float* row) {
  return MaterialRow{row[kMatModel], row[kMatMu], row[kMatLambda], row[kMatBulk],
                     {row[kMatParameter], row[kMatParameter + 1], row[kMatParameter + 2]}};
}

// The strain of a trial state as a law sees it: isotropic laws need only these invariants.
struct StrainInvariants {
  double e;               // volumetric Hencky strain ln J
  double inverse_J;       // 1 / J (Cauchy stress = tau / J)
  double dev_norm;        // |dev eps|
  double dev_max;         // largest principal deviatoric strain (an upper bound on the series path)
  double dev_norm_error;  // bound of the error of dev_norm (0 where the path computes it exactly)
};

// What a law did to one particle.
struct LawResult {
  double dev_scale;  // dev eps of F_E = dev_scale dev eps of F_trial (1: unchanged, 0: a tip)
  double e_out;      // ln det F_E
  double shear;      // tau = 2 mu shear dev eps + K volume I where the law is linear in the strain
  double volume;     //   (linear_principal_stress; a law with a spectral split has its own)
  double decided;    // > 0 where the series path may keep this result: the state is clear of the
                     // law's thresholds by more than the strain's error, its stress is linear, and
                     // it dissipates nothing
  float projected;   // 1 where F_E differs from F_trial (a float: GCC 12 cannot vectorise a bool select)
  float state[kStateCapacity];  // the new state (fields [0, kStateFields) of the model)
};

// A LawResult that keeps F and the state (fields [0, Fields) copied from `state`) with the linear
// Hencky stress: the start of every law.
template <int Fields>
HOST_DEVICE FGS_FORCE_INLINE LawResult elastic_result(const float* state, const StrainInvariants& s) {
  LawResult r;
  r.dev_scale = 1.0;
  r.e_out = s.e;
  r.shear = 1.0;
  r.volume = s.e;
  r.decided = 1.0;
  r.projected = 0.f;
  FGS_UNROLL
  for (int k = 0; k < Fields; ++k) r.state[k] = state[k];
  return r;
}

// tau_i = 2 mu shear dev_i + K volume: the principal stress of a law linear in the strain.
HOST_DEVICE FGS_FORCE_INLINE double linear_principal_stress(const MaterialRow& m, const LawResult& r, double dev_i) {
  const double mu = m.mu, lambda = m.lambda;
  const double bulk_term = (lambda + (2.0 / 3.0) * mu) * r.volume;
  return 2.0 * mu * r.shear * dev_i + bulk_term;
}

// psi = mu |eps|^2 + lambda / 2 (tr eps)^2 of principal Hencky strains eps with trace e.
HOST_DEVICE FGS_FORCE_INLINE double hencky_energy_density(const MaterialRow& m, const double eps[3], double e) {
  const double mu = m.mu, lambda = m.lambda;
  return mu * (eps[0] * eps[0] + eps[1] * eps[1] + eps[2] * eps[2]) + 0.5 * lambda * e * e;
}

// The parts a model whose stress is the Hencky one of F_E shares: the linear principal stress, the
// Hencky energy, and no dissipation. A model derives from it and writes its own update (and
// whatever else differs).
struct HenckyLaw {
  HOST_DEVICE FGS_FORCE_INLINE static double principal_stress(const MaterialRow& m, const LawResult& r, double dev_i,
                                                              double) {
    return linear_principal_stress(m, r, dev_i);
  }

  HOST_DEVICE FGS_FORCE_INLINE static double dissipated(const MaterialRow&, const float*, const LawResult&,
                                                        const double*, double) {
    return 0.0;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double energy(const MaterialRow& m, const float*, const double eps[3], double e) {
    return hencky_energy_density(m, eps, e);
  }
};

}  // namespace fgs
