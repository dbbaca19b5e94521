// model: von_mises (fracture_gs/materials/von_mises.py; docs/formulas.md, "Von Mises plasticity"):
// J2 plasticity with linear isotropic hardening on the Hencky strain, a ductile metal. State field 0 is
// the equivalent plastic strain eps_p; a particle counts as fractured once it reaches the material's
// failure strain.
//
// Return map (exact for Hencky strain and an isotropic law): the trial Kirchhoff deviator has the norm
// |dev tau| = 2 mu |dev eps|; the yield function is f = |dev tau| - sqrt(2/3) (sigma_y + H eps_p).
// Where f > 0 the deviator shrinks radially by dgamma = f / (2 mu + 2/3 H) (volume kept) and
// eps_p grows by sqrt(2/3) dgamma. The update dissipates the elastic energy the projection removes,
// mu (|dev eps|^2 - |dev eps'|^2).
#pragma once
#include <cmath>

#include "common/fast_math.h"
#include "common/material_law.h"

namespace fgs {

struct VonMisesModel : HenckyLaw {
  static constexpr int kCode = 3;
  static constexpr const char* kName = "von_mises";
  // yield_stress: sigma_y (Pa); hardening: H (Pa), the slope of the yield stress over eps_p.
  static constexpr const char* kParameters[kMatParameters] = {"yield_stress", "hardening", ""};
  enum Parameter : int { kYieldStress = 0, kHardening = 1 };
  static constexpr int kStateFields = 1;
  static constexpr const char* kState[kStateFields] = {"plastic_strain"};

  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow& m, const float* state,
                                                       const StrainInvariants& s) {
    const double mu = m.mu, H = m.parameter[kHardening];
    const double plastic = state[0];
    const double radius = 0.81649658092772603273 * (m.parameter[kYieldStress] + H * plastic);  // sqrt(2/3) (...)
    const double trial = 2.0 * mu * s.dev_norm;
    const double f = trial - radius;
    const bool yields = f > 0.0;
    const double dgamma = yields ? f / (2.0 * mu + (2.0 / 3.0) * H) : 0.0;
    LawResult r = elastic_result<kStateFields>(state, s);
    r.dev_scale = yields ? 1.0 - 2.0 * mu * dgamma / (trial > 0.0 ? trial : 1.0) : 1.0;
    r.shear = r.dev_scale;
    r.state[0] = (float)(plastic + 0.81649658092772603273 * dgamma);
    r.projected = yields ? 1.f : 0.f;
    // The series path keeps states inside the yield surface by more than the error of |dev eps|.
    r.decided = -f - 2.0 * mu * s.dev_norm_error;
    return r;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double dissipated(const MaterialRow& m, const float*, const LawResult& r,
                                                        const double dev[3], double) {
    const double norm_sq = dev[0] * dev[0] + dev[1] * dev[1] + dev[2] * dev[2];
    return (double)m.mu * (1.0 - r.dev_scale * r.dev_scale) * norm_sq;
  }
};

}  // namespace fgs
