// model: nacc (fracture_gs/materials/nacc.py; docs/formulas.md, "NACC plasticity"): the
// non-associated Cam-clay return map of Wolper et al. 2019 with CD-MPM hardening, on the strain
// invariants. State field 0 is the hardening variable alpha (alpha0 = ln J_p0). Its plastic work is
// not counted as dissipated energy (the energy checks only need that it never adds any).
#pragma once
#include <cmath>

#include "common/fast_math.h"
#include "common/material_law.h"

namespace fgs {

constexpr double kNaccP0Floor = 1e-5;  // p0 = K (1e-5 + sinh(xi max(-alpha, 0)))
// y > kNaccYieldTol (M p0)^2 triggers the projection: relative to the ellipse's own size, so a
// particle with p0 at its floor 1e-5 K is still projected and hardened (docs/design_mpm.md, "NACC
// tolerances"). Hardening is gated relative to p0 only: -beta p0 < p < p0.
constexpr double kNaccYieldTol = 1e-6;

struct NaccModel : HenckyLaw {
  static constexpr int kCode = 1;
  static constexpr const char* kName = "nacc";
  static constexpr const char* kParameters[kMatParameters] = {"beta", "xi", "M"};
  enum Parameter : int { kBeta = 0, kXi = 1, kM = 2 };
  static constexpr int kStateFields = 1;
  static constexpr const char* kState[kStateFields] = {"alpha"};

  // The return map in invariants: p = -K e, q = sqrt(3/2) 2 mu |dev eps|, the yield ellipse
  // y = (1 + 2 beta) q^2 + M^2 (p + beta p0)(p - p0) <= 0; outside it the deviator shrinks radially
  // onto the ellipse (volume kept), beyond the tips the state goes to the tip.
  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow& m, const float* state,
                                                       const StrainInvariants& s) {
    const double mu = m.mu, K = m.bulk, beta = m.parameter[kBeta], M = m.parameter[kM];
    const double e = s.e;
    const double a = state[0];
    const double p0 =
        K * (kNaccP0Floor + fast_math::sinh_nonnegative_d(m.parameter[kXi] * fast_math::max_of(-a, 0.0)));
    const double p = -K * e;
    const double q = 1.2247448713915890491 * 2.0 * mu * s.dev_norm;  // sqrt(3/2) 2 mu |dev|
    const bool compression_tip = p > p0;
    const bool tension_tip = !compression_tip & (p < -beta * p0);
    const bool tip = compression_tip | tension_tip;
    const double y = (1.0 + 2.0 * beta) * q * q + M * M * (p + beta * p0) * (p - p0);
    const double y_tol = kNaccYieldTol * (M * p0) * (M * p0);
    const bool ellipse = !tip & (y > y_tol);
    const double e_tip = compression_tip ? -p0 / K : beta * p0 / K;
    const double q_new = M * sqrt(fast_math::max_of((p + beta * p0) * (p0 - p) / (1.0 + 2.0 * beta), 0.0));
    const double scale = q > 0.0 ? q_new / (q > 0.0 ? q : 1.0) : 0.0;
    // CD-MPM hardening: alpha moves as if p went to the ellipse along the ray from its centre.
    const double pc = 0.5 * (1.0 - beta) * p0;
    const double half_axis = 0.5 * (1.0 + beta) * p0;
    const double ray = sqrt((1.0 + 2.0 * beta) * q * q + M * M * (p - pc) * (p - pc));
    const double p_final = pc + M * half_axis / (ray > 0.0 ? ray : 1.0) * (p - pc);
    const bool harden = ellipse & (-beta * p0 < p) & (p < p0) & (ray > 0.0);
    LawResult r = elastic_result<kStateFields>(state, s);
    r.state[0] = (float)(tip ? a + (e - e_tip) : (harden ? a + (p_final - p) / K : a));
    r.dev_scale = tip ? 0.0 : (ellipse ? scale : 1.0);
    r.e_out = tip ? e_tip : e;
    r.shear = r.dev_scale;
    r.volume = r.e_out;
    r.projected = (tip | ellipse) ? 1.f : 0.f;
    // The error of |dev eps| moves y by at most dy: closer than that to the threshold, the
    // decision is not final.
    const double dq = 1.2247448713915890491 * 2.0 * mu * s.dev_norm_error;
    const double dy = (1.0 + 2.0 * beta) * dq * (2.0 * q + dq);
    r.decided = fast_math::max_of(fast_math::abs_of(y - y_tol) - dy, tip ? 1.0 : 0.0);
    return r;
  }
};

}  // namespace fgs
