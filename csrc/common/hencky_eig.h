// The constitutive update of csrc/common/constitutive.h without an SVD: float32, branch-free,
// written so that GCC vectorises a loop over particles that calls it (the CPU kernels run
// it 8 or 16 particles per instruction; see csrc/mpm/constitutive_batch.h).
//
// Every model here is isotropic, so the stress and the return map only need the eigen-
// decomposition of the left Cauchy-Green tensor b = F F^T = Q diag(s) Q^T, s_i = sigma_i^2:
//   Hencky strain   eps_i = ln sigma_i = 1/2 log1p(|Q_i^T F|^2 - 1),  Q = eigenvectors of b - I
//   Kirchhoff       tau = Q diag(2 mu eps + lambda_L tr eps) Q^T
//   return map      F_E = U diag(e^eps') V^T = Q diag(e^(eps' - eps)) Q^T F
// (V^T = diag(sigma)^-1 U^T F and U = Q up to column signs, which cancel). b - I is formed in
// double from the float F (exact products), so its eigenvalues carry the strain to float
// *relative* accuracy even for strains of 1e-5 and any rotation, and the stress error is a few
// float ulp of the stress: the eigenvector error (~1e-7 |b - I| / gap) is multiplied by
// differences of principal stresses (~mu gap).
//
// The eigen-decomposition is cyclic Jacobi with a fixed number of sweeps (no data-dependent
// loop, so every SIMD lane does the same work and a particle's result does not depend on its
// neighbours in the batch).
//
// Not handled here (the caller falls back to the SVD path, constitutive_update): inverted or
// nearly singular F (det F <= 0 or sigma_min < 1e-3, where the Hencky clamp and the sign
// convention of svd3 matter), non-finite input, unknown model codes. The function reports
// whether its result is valid.
#pragma once
#include <cmath>

#include "common/constitutive.h"
#include "common/fast_math.h"
#include "common/hd.h"

namespace fgs {

constexpr int kJacobiSweeps = 4;  // cyclic Jacobi sweeps of sym3_eigenvectors
// b's smallest eigenvalue sigma_min^2 must exceed this for the eigen path (sigma_min > 1e-3).
constexpr float kEigMinStretchSq = 1e-6f;

namespace hencky_eig_detail {

// One Jacobi rotation in the (p, q) plane that zeroes a_pq of a symmetric 3x3 matrix; r is the
// third index. The columns p, q of Q (row-major, eigenvectors as columns) rotate with it.
template <int P, int Qc, class T>
HOST_DEVICE FGS_FORCE_INLINE void jacobi_rotation(T& app, T& aqq, T& apq, T& arp, T& arq, T Q[9]) {
  const T d = aqq - app;
  const T h = sqrt(d * d + T(4) * apq * apq);
  const T den = (d < T(0) ? -d : d) + h;
  T t = T(2) * apq / (den > T(0) ? den : T(1));  // tan of the rotation angle, |t| <= 1
  t = d < T(0) ? -t : t;
  const T c = T(1) / sqrt(T(1) + t * t);
  const T s = t * c;
  app -= t * apq;
  aqq += t * apq;
  apq = T(0);
  const T rp = arp, rq = arq;
  arp = c * rp - s * rq;
  arq = s * rp + c * rq;
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) {
    const T qp = Q[3 * i + P], qq = Q[3 * i + Qc];
    Q[3 * i + P] = c * qp - s * qq;
    Q[3 * i + Qc] = s * qp + c * qq;
  }
}

}  // namespace hencky_eig_detail

// One cyclic Jacobi sweep (T = float or double): rotations in the (0,1), (0,2), (1,2) planes.
template <class T>
HOST_DEVICE FGS_FORCE_INLINE void jacobi_sweep(T& a00, T& a11, T& a22, T& a01, T& a02, T& a12, T Q[9]) {
  using hencky_eig_detail::jacobi_rotation;
  jacobi_rotation<0, 1>(a00, a11, a01, a02, a12, Q);
  jacobi_rotation<0, 2>(a00, a22, a02, a01, a12, Q);
  jacobi_rotation<1, 2>(a11, a22, a12, a01, a02, Q);
}

// Eigenvectors of the symmetric E = [[e00 e01 e02] [e01 e11 e12] [e02 e12 e22]], computed in
// float: kJacobiSweeps cyclic sweeps from Q = I leave an off-diagonal of float round-off
// (~1e-7 |E|). Q is orthogonal to float precision (row-major, eigenvectors as columns),
// unsorted, returned in double for the products that follow. The sweeps are written out: a
// loop here would keep GCC from vectorising callers.
HOST_DEVICE FGS_FORCE_INLINE void sym3_eigenvectors(const double E[6], double Q[9]) {
  static_assert(kJacobiSweeps == 4, "sym3_eigenvectors writes out kJacobiSweeps sweeps");
  float a00 = (float)E[0], a11 = (float)E[1], a22 = (float)E[2], a01 = (float)E[3], a02 = (float)E[4],
        a12 = (float)E[5];
  float Qf[9];
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) Qf[i] = (i % 4 == 0) ? 1.f : 0.f;
  jacobi_sweep(a00, a11, a22, a01, a02, a12, Qf);
  jacobi_sweep(a00, a11, a22, a01, a02, a12, Qf);
  jacobi_sweep(a00, a11, a22, a01, a02, a12, Qf);
  jacobi_sweep(a00, a11, a22, a01, a02, a12, Qf);
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) Q[i] = Qf[i];
}

// b - I = F F^T - I (entries 00 11 22 01 02 12) and det F, in double: float products are exact
// there. Fd receives F in double.
HOST_DEVICE FGS_FORCE_INLINE double cauchy_green_minus_identity(const float F[9], double Fd[9], double b[6]) {
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) Fd[i] = F[i];
  b[0] = Fd[0] * Fd[0] + Fd[1] * Fd[1] + Fd[2] * Fd[2] - 1.0;
  b[1] = Fd[3] * Fd[3] + Fd[4] * Fd[4] + Fd[5] * Fd[5] - 1.0;
  b[2] = Fd[6] * Fd[6] + Fd[7] * Fd[7] + Fd[8] * Fd[8] - 1.0;
  b[3] = Fd[0] * Fd[3] + Fd[1] * Fd[4] + Fd[2] * Fd[5];
  b[4] = Fd[0] * Fd[6] + Fd[1] * Fd[7] + Fd[2] * Fd[8];
  b[5] = Fd[3] * Fd[6] + Fd[4] * Fd[7] + Fd[5] * Fd[8];
  return Fd[0] * (Fd[4] * Fd[8] - Fd[5] * Fd[7]) - Fd[1] * (Fd[3] * Fd[8] - Fd[5] * Fd[6]) +
         Fd[2] * (Fd[3] * Fd[7] - Fd[4] * Fd[6]);
}

// Material parameters of one table row (see MatField) and the particle's tensile strength.
// c4..c6 are the model's own parameters: NACC beta, xi, M; brittle median strength, crack band
// constant, residual.
struct MaterialRow {
  float model, mu, lambda, bulk, c4, c5, c6, strength;
};

// The NACC return map (docs/formulas.md) on the strain invariants, in double: what both update paths
// below need. e: volumetric Hencky strain ln det F; dev_norm: |dev eps|; alpha: the old alpha.
struct InvariantReturn {
  double g;          // new dev eps = g dev eps: 1 inside (and for the elastic and brittle models),
                     // the radial scale on the ellipse (volume kept), 0 at the tips
  double e_out;      // new volumetric strain
  double alpha;      // new alpha (brittle: new damage d)
  double shear;      // tau = 2 mu shear dev eps + K volume I: shear = g and volume = e_out (NACC,
  double volume;     // elastic; brittle: g(d) and e, exact for undamaged particles only - damaged ones
                     // need the principal strains, brittle_principal_stress)
  double driving;    // brittle: undegraded largest principal Cauchy stress (0 for other models)
  double q;          // sqrt(3/2) 2 mu |dev eps| of the trial state
  double y;          // yield function of the trial state
  double y_tol;      // the state is projected where y > y_tol (nacc_yield_tolerance)
  float projected;   // 1 if the state was projected (a float: GCC 12 cannot vectorise a select on a bool)
  float tip;         // 1 if projected to a tip
};

HOST_DEVICE FGS_FORCE_INLINE InvariantReturn nacc_invariant_return(const MaterialRow& m, float alpha, double e,
                                                         double dev_norm) {
  const bool is_nacc = m.model == (float)kModelNacc;
  const double mu = m.mu, K = m.bulk, beta = m.c4, M = m.c6;
  const double a = alpha;
  const double p0 = K * (kNaccP0Floor + fast_math::sinh_nonnegative_d(m.c5 * fast_math::max_of(-a, 0.0)));
  const double p = -K * e;
  const double q = 1.2247448713915890491 * 2.0 * mu * dev_norm;  // sqrt(3/2) 2 mu |dev|
  const bool compression_tip = p > p0;
  const bool tension_tip = !compression_tip & (p < -beta * p0);
  const bool tip = is_nacc & (compression_tip | tension_tip);
  const double y = (1.0 + 2.0 * beta) * q * q + M * M * (p + beta * p0) * (p - p0);
  const double y_tol = nacc_yield_tolerance(p0, M);
  const bool ellipse = is_nacc & !tip & (y > y_tol);
  const double e_tip = compression_tip ? -p0 / K : beta * p0 / K;
  const double q_new = M * sqrt(fast_math::max_of((p + beta * p0) * (p0 - p) / (1.0 + 2.0 * beta), 0.0));
  const double scale = q > 0.0 ? q_new / (q > 0.0 ? q : 1.0) : 0.0;
  // CD-MPM hardening: alpha moves as if p went to the ellipse along the ray from its centre.
  const double pc = 0.5 * (1.0 - beta) * p0;
  const double half_axis = 0.5 * (1.0 + beta) * p0;
  const double ray = sqrt((1.0 + 2.0 * beta) * q * q + M * M * (p - pc) * (p - pc));
  const double p_final = pc + M * half_axis / (ray > 0.0 ? ray : 1.0) * (p - pc);
  const bool harden = ellipse & (-beta * p0 < p) & (p < p0) & (ray > 0.0);
  InvariantReturn r;
  r.alpha = tip ? a + (e - e_tip) : (harden ? a + (p_final - p) / K : a);
  r.g = tip ? 0.0 : (ellipse ? scale : 1.0);
  r.e_out = tip ? e_tip : e;
  r.q = q;
  r.y = y;
  r.y_tol = y_tol;
  r.projected = (tip | ellipse) ? 1.f : 0.f;
  r.tip = tip ? 1.f : 0.f;
  r.shear = r.g;
  r.volume = r.e_out;
  r.driving = 0.0;
  return r;
}

// The update of any model on the strain invariants: NACC's return map (nacc_invariant_return) or the
// brittle damage law (brittle_response). dev_max: the largest principal deviatoric strain (the
// brittle driving stress needs it; an upper bound gives an upper bound of the driving stress).
// det: det F (J).
HOST_DEVICE FGS_FORCE_INLINE InvariantReturn invariant_update(const MaterialRow& m, float alpha, double e, double det,
                                                              double dev_norm, double dev_max) {
  InvariantReturn r = nacc_invariant_return(m, alpha, e, dev_norm);
  const bool is_brittle = m.model == (float)kModelBrittle;
  const BrittleResponse b = brittle_response(m.mu, m.bulk, m.strength, m.c5, m.c6, alpha, e,
                                             1.0 / (det > 0.0 ? det : 1.0), dev_max);
  r.alpha = is_brittle ? b.damage : r.alpha;
  r.shear = is_brittle ? b.g : r.shear;
  r.volume = is_brittle ? e : r.volume;
  r.driving = is_brittle ? b.driving : 0.0;
  return r;
}

// What the return map did to one particle, for projected_deformation: F_E = Q diag(exp(log_
// stretch_i)) Q^T F / |Q_i|^2 where `projected` is non-zero, F itself elsewhere.
struct EigProjection {
  double Q[9];             // eigenvectors of b (columns, orthogonal to float precision)
  double log_stretch[3];   // eps_out_i - eps_i
  float projected;         // 1 if the state was projected onto the yield surface, else 0
};

// Constitutive update (elastic, NACC or brittle) through the eigen-decomposition of b, first
// half: the return map's decisions, alpha and the Kirchhoff stress of F_E. F: F_trial; alpha
// in/out; tau: Kirchhoff stress of F_E; proj: what projected_deformation needs to form F_E.
// Returns false (outputs meaningless) where the caller must use constitutive_update instead:
// see the file comment.
// dissipated: the energy per unit rest volume the brittle damage took in this update (0 otherwise).
HOST_DEVICE FGS_FORCE_INLINE bool constitutive_stress_eig(const MaterialRow& m, const float F[9], float* alpha,
                                                float tau[9], EigProjection* proj, float* dissipated) {
  double Fd[9], b[6];
  const double det = cauchy_green_minus_identity(F, Fd, b);
  double Q[9];
  sym3_eigenvectors(b, Q);

  const float a = *alpha;
  float probe = a * 0.f;  // NaN/Inf anywhere in the input makes it non-zero
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) probe += F[i] * 0.f;
  // sigma_i^2 = |Q_i^T F|^2 / |Q_i|^2 in double. The rows of Q^T F are orthogonal, so an
  // eigenvector error delta only enters as delta^2: the stretches keep their relative accuracy
  // when sigma_min << sigma_max (where lam_min carries an error of ~1e-7 |b - I|), and the
  // strains theirs when they are tiny (the division removes Q's float normalisation error).
  double stretch_sq[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) {
    const double q0 = Q[i], q1 = Q[3 + i], q2 = Q[6 + i];
    double row_norm2 = 0.0;
  #pragma GCC unroll 9
    for (int k = 0; k < 3; ++k) {
      const double r = q0 * Fd[k] + q1 * Fd[3 + k] + q2 * Fd[6 + k];
      row_norm2 += r * r;
    }
    stretch_sq[i] = row_norm2 / (q0 * q0 + q1 * q1 + q2 * q2);
  }
  const double stretch_sq_min = fast_math::min_of(fast_math::min_of(stretch_sq[0], stretch_sq[1]), stretch_sq[2]);
  const bool is_elastic = m.model == (float)kModelElastic, is_nacc = m.model == (float)kModelNacc,
             is_brittle = m.model == (float)kModelBrittle;
  // Bitwise & and | (no short circuit) on the conditions: branches would stop the vectoriser.
  const bool valid = (probe == 0.f) & (det > 0.0) & (stretch_sq_min > (double)kEigMinStretchSq) &
                     (is_elastic | is_nacc | is_brittle);

  // From here on double (the loop stays vectorised, 4 lanes per instruction): in float the
  // return map lands ~1e-5 K^2 off the yield surface for strains of order 1, where y is a
  // small difference of large terms.
  //
  // Principal Hencky strains eps_i, their trace e = ln det F (from det F itself: the sum of the
  // eps_i would lose the small volumetric strain of a large deviatoric one to cancellation, and
  // after a projection the stress is mostly that volumetric part) and the deviator.
  double eps[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i)
    eps[i] = 0.5 * fast_math::log1p_d(fast_math::max_of(stretch_sq[i], (double)kEigMinStretchSq) - 1.0);
  const double e = fast_math::log1p_d(det > 0.0 ? det - 1.0 : 0.0);
  double dev[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) dev[i] = eps[i] - e * (1.0 / 3.0);
  const double dev_norm = sqrt(dev[0] * dev[0] + dev[1] * dev[1] + dev[2] * dev[2]);

  const double mu = m.mu, lambda = m.lambda;
  const double dev_max = fast_math::max_of(fast_math::max_of(dev[0], dev[1]), dev[2]);
  const InvariantReturn ret = invariant_update(m, a, e, det, dev_norm, dev_max);
  *alpha = (float)ret.alpha;
  proj->projected = ret.projected;
  const double g = ret.g;
  const double e_out = ret.e_out;
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) proj->Q[i] = Q[i];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) proj->log_stretch[i] = (g - 1.0) * dev[i] + (e_out - e) * (1.0 / 3.0);
  // tau = Q diag(2 mu eps_out + lambda tr eps_out) Q^T = Q diag(2 mu g dev + K e_out) Q^T (NACC,
  // elastic); the brittle model's principal stresses degrade the tensile principal strains.
  const double bulk_term = (lambda + (2.0 / 3.0) * mu) * ret.volume;
  double d[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) {
    const double brittle = brittle_principal_stress(mu, lambda, ret.shear, dev[i] + e * (1.0 / 3.0), e);
    d[i] = is_brittle ? brittle : 2.0 * mu * ret.shear * dev[i] + bulk_term;
  }
  const double principal_strain[3] = {dev[0] + e * (1.0 / 3.0), dev[1] + e * (1.0 / 3.0), dev[2] + e * (1.0 / 3.0)};
  const double taken = (brittle_degradation(a, m.c6) - ret.shear) * brittle_tensile_energy(mu, lambda, principal_strain, e);
  *dissipated = is_brittle ? (float)taken : 0.f;
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 9
    for (int j = i; j < 3; ++j) {
      const float t = (float)(Q[3 * i] * d[0] * Q[3 * j] + Q[3 * i + 1] * d[1] * Q[3 * j + 1] +
                              Q[3 * i + 2] * d[2] * Q[3 * j + 2]);
      tau[3 * i + j] = t;
      tau[3 * j + i] = t;
    }
  return valid;
}


// Second half of the update: F_E = Q diag(exp(eps_out - eps)) Q^T F where the state was projected
// (with Q's columns normalised: Q is orthogonal only to float precision), F itself elsewhere.
HOST_DEVICE FGS_FORCE_INLINE void projected_deformation(const EigProjection& proj, const float F[9], float F_out[9]) {
  const double* Q = proj.Q;
  double Fd[9];
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) Fd[i] = F[i];
  double stretch[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) {
    const double q0 = Q[i], q1 = Q[3 + i], q2 = Q[6 + i];
    stretch[i] = fast_math::exp_d(proj.log_stretch[i]) / (q0 * q0 + q1 * q1 + q2 * q2);
  }
  double S[9];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 9
    for (int j = i; j < 3; ++j) {
      const double t = Q[3 * i] * Q[3 * j] * stretch[0] + Q[3 * i + 1] * Q[3 * j + 1] * stretch[1] +
                       Q[3 * i + 2] * Q[3 * j + 2] * stretch[2];
      S[3 * i + j] = t;
      S[3 * j + i] = t;
    }
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 9
    for (int j = 0; j < 3; ++j) {
      const double projected_entry = S[3 * i] * Fd[j] + S[3 * i + 1] * Fd[3 + j] + S[3 * i + 2] * Fd[6 + j];
      F_out[3 * i + j] = (proj.projected > 0.f) ? (float)projected_entry : F[3 * i + j];
    }
}

// ---------------------------------------------------------------------------------------------
// Moderate deviatoric strains: no eigen-decomposition at all.
//
// b = J^(2/3) b_iso with J = det F and det b_iso = 1, so eps = e/3 I + 1/2 log(b_iso), e = ln J:
// the volumetric part is a scalar (e in double, from det F as on the eigen path) and only the
// isochoric part needs a matrix function. With X = b_iso - I = J^(-2/3) (b - I) + (J^(-2/3) - 1) I
// (formed in double from b - I, so a large volume change costs no accuracy),
//   1/2 log(I + X) = atanh(Y),  Y = X (2I + X)^-1,  atanh(Y) = Y + Y^3/3 + Y^5/5 + ...
// (per eigenvalue lambda of b_iso: 1/2 ln lambda = atanh((lambda - 1) / (lambda + 1))). The return
// map only needs invariants, e and |dev eps| (dev eps = atanh(Y) made traceless), then
// tau = 2 mu g dev eps + K e_out I and F_E = exp(Z) F with
// Z = eps_out - eps = (e_out - e) / 3 I + (g - 1) dev eps: the left stretch V = exp(eps) of
// F = V R is replaced by exp(eps_out). exp(Z) = exp((e_out - e) / 3) exp(W), W = (g - 1) dev eps,
// the scalar in double, exp(W) a Taylor series.
// With |Y|_F <= kSmallStrainNorm = 0.25 (isochoric principal stretches in [0.77, 1.29], any volume
// change) the atanh series to Y^11 is exact to |Y|^12 / 13, < 5e-9 relative, and with
// |W|_F <= kSmallStrainNorm the exp series to W^6 to |W|^7 / 7! < 1.3e-8; both run in float (the
// products are well scaled), the return map's algebra in double (nacc_invariant_return). States
// within the float error of |dev eps| of the yield surface are left to the eigen path, so both
// paths decide alike.

constexpr float kSmallStrainNorm = 0.25f;  // |Y|_F and |W|_F bound of the series path
// det F must exceed this (e^-19) on the series path: then b's eigenvalues exceed
// 0.6 J^(2/3) > kEigMinStretchSq (|Y| <= 0.25 keeps b_iso's above 0.6), so the eigen path would
// accept the state too.
constexpr double kSmallStrainMinDet = 5.6e-9;

namespace hencky_eig_detail {

// R = X P for symmetric X and a polynomial P of X (so R is symmetric); entries 00 11 22 01 02 12.
HOST_DEVICE FGS_FORCE_INLINE void sym3_product(const float X[6], const float P[6], float R[6]) {
  R[0] = X[0] * P[0] + X[3] * P[3] + X[4] * P[4];
  R[1] = X[3] * P[3] + X[1] * P[1] + X[5] * P[5];
  R[2] = X[4] * P[4] + X[5] * P[5] + X[2] * P[2];
  R[3] = X[0] * P[3] + X[3] * P[1] + X[4] * P[5];
  R[4] = X[0] * P[4] + X[3] * P[5] + X[4] * P[2];
  R[5] = X[3] * P[4] + X[1] * P[5] + X[5] * P[2];
}

// One Horner step P <- c I + X P.
HOST_DEVICE FGS_FORCE_INLINE void horner_step(const float X[6], float c, float P[6]) {
  float R[6];
  sym3_product(X, P, R);
#pragma GCC unroll 6
  for (int i = 0; i < 6; ++i) P[i] = R[i] + (i < 3 ? c : 0.f);
}

// P = c[0] I + X (c[1] I + X (c[2] I + ... + X c[N-1] I)), by Horner.
template <int N>
HOST_DEVICE FGS_FORCE_INLINE void sym3_polynomial(const float X[6], const float (&c)[N], float P[6]) {
  P[0] = P[1] = P[2] = c[N - 1];
  P[3] = P[4] = P[5] = 0.f;
#pragma GCC unroll 16
  for (int k = N - 2; k >= 0; --k) horner_step(X, c[k], P);
}

HOST_DEVICE FGS_FORCE_INLINE float sym3_norm_sq(const float X[6]) {
  return X[0] * X[0] + X[1] * X[1] + X[2] * X[2] + 2.f * (X[3] * X[3] + X[4] * X[4] + X[5] * X[5]);
}

}  // namespace hencky_eig_detail

// The constitutive update at small to moderate deviatoric strain (the series path). F: F_trial in;
// F_out: F_E; alpha in/out;
// tau: Kirchhoff stress of F_E. Returns false (outputs meaningless) where the caller must run
// the eigen path (constitutive_stress_eig) instead: isochoric strains beyond kSmallStrainNorm, a
// state within float error of the yield surface, or anything the eigen path rejects.
HOST_DEVICE FGS_FORCE_INLINE bool constitutive_small_strain(const MaterialRow& m, const float F[9], float* alpha,
                                                  float F_out[9], float tau[9]) {
  using hencky_eig_detail::sym3_norm_sq;
  using hencky_eig_detail::sym3_polynomial;
  using hencky_eig_detail::sym3_product;
  double Fd[9], b[6];
  const double det = cauchy_green_minus_identity(F, Fd, b);
  const double e = fast_math::log1p_d(det > 0.0 ? det - 1.0 : 0.0);
  // X = b_iso - I = s (b - I) + (s - 1) I with s = J^(-2/3). s in float is enough: an error
  // d s changes X by (d s / s)(I + X), whose isotropic part the traceless projection below
  // removes, leaving a relative error of float rounding on X.
  const double s = (double)fast_math::exp_f((float)(e * (-2.0 / 3.0)));
  float X[6];
#pragma GCC unroll 6
  for (int i = 0; i < 6; ++i) X[i] = (float)(s * b[i] + (i < 3 ? s - 1.0 : 0.0));
  const float a = *alpha;
  float probe = a * 0.f;  // NaN/Inf anywhere in the input makes it non-zero
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) probe += F[i] * 0.f;

  // eps_iso = 1/2 log(I + X) = atanh(Y) with Y = X (2I + X)^-1 (a function of X, so they
  // commute and Y is symmetric): atanh(Y) = Y (I + Y^2/3 + Y^4/5 + ... + Y^10/11), by Horner.
  float Y[6];
  {
    const float m0 = X[0] + 2.f, m1 = X[1] + 2.f, m2 = X[2] + 2.f, m3 = X[3], m4 = X[4], m5 = X[5];
    float inverse[6] = {m1 * m2 - m5 * m5, m0 * m2 - m4 * m4, m0 * m1 - m3 * m3,
                        m4 * m5 - m3 * m2, m3 * m5 - m4 * m1, m3 * m4 - m0 * m5};  // adjugate
    const float inv_det = 1.f / (m0 * inverse[0] + m3 * inverse[3] + m4 * inverse[4]);
#pragma GCC unroll 6
    for (int i = 0; i < 6; ++i) inverse[i] *= inv_det;
    sym3_product(X, inverse, Y);
  }
  const float y_norm_sq = sym3_norm_sq(Y);
  float Y2[6];
  sym3_product(Y, Y, Y2);
  const float atanh_coefficients[6] = {1.f, 1.f / 3.f, 1.f / 5.f, 1.f / 7.f, 1.f / 9.f, 1.f / 11.f};
  float P[6];
  sym3_polynomial(Y2, atanh_coefficients, P);
  float eps_iso[6];  // traceless up to float rounding; made exactly so below
  sym3_product(Y, P, eps_iso);
  const double trace_third = ((double)eps_iso[0] + (double)eps_iso[1] + (double)eps_iso[2]) * (1.0 / 3.0);
  double dev[6];
#pragma GCC unroll 6
  for (int i = 0; i < 6; ++i) dev[i] = (double)eps_iso[i] - (i < 3 ? trace_third : 0.0);
  const double dev_norm = sqrt(dev[0] * dev[0] + dev[1] * dev[1] + dev[2] * dev[2] +
                               2.0 * (dev[3] * dev[3] + dev[4] * dev[4] + dev[5] * dev[5]));

  const bool is_elastic = m.model == (float)kModelElastic, is_nacc = m.model == (float)kModelNacc,
             is_brittle = m.model == (float)kModelBrittle;
  // The largest eigenvalue of a traceless symmetric matrix is at most sqrt(2/3) of its norm: the
  // brittle driving stress computed from that bound is an upper bound of the true one.
  const InvariantReturn ret = invariant_update(m, a, e, det, dev_norm, 0.81649658092772603273 * dev_norm);
  // The float error of |dev eps| (a few ulp of |eps_iso| <= 1.03 |Y|) moves y by at most dy:
  // closer than that to the threshold, the decision is left to the eigen path.
  const double mu = m.mu, beta = m.c4;
  const double q = ret.q;
  const double dq = 1.2247448713915890491 * 2.0 * mu * (2e-6 * (double)sqrtf(y_norm_sq) + 1e-12);
  const double dy = (1.0 + 2.0 * beta) * dq * (2.0 * q + dq);
  // decided > 0 where y is farther than dy from the threshold, or the state goes to a tip, or
  // the model is elastic (a double, not a bool: GCC 12 cannot vectorise that mix of conditions).
  // A brittle state is decided where it is undamaged and the bound of its driving stress stays below
  // the particle's strength (no new damage, whatever the true largest principal stress: the stress is
  // the undamaged one); damaged states need the principal strains of the eigen path (spectral split).
  const double nacc_decided = fast_math::max_of(fast_math::abs_of(ret.y - ret.y_tol) - dy,
                                                (double)(ret.tip + (is_elastic ? 1.f : 0.f)));
  const bool brittle_decided = (ret.driving < (double)m.strength) & (a == 0.f);
  const double decided = is_brittle ? (brittle_decided ? 1.0 : -1.0) : nacc_decided;
  *alpha = (float)ret.alpha;

  // exp(W) = I + W P, P = sum_k W^(k-1) / k! for k = 1..6, by Horner; W = (g - 1) dev eps.
  float W[6];
#pragma GCC unroll 6
  for (int i = 0; i < 6; ++i) W[i] = (float)((ret.g - 1.0) * dev[i]);
  const float w_norm_sq = sym3_norm_sq(W);
  const float exp_coefficients[6] = {1.f, 1.f / 2.f, 1.f / 6.f, 1.f / 24.f, 1.f / 120.f, 1.f / 720.f};
  float E[6];
  sym3_polynomial(W, exp_coefficients, E);
  float expW[6];
  sym3_product(W, E, expW);
  // exp(Z) = exp((e_out - e) / 3) exp(W).
  const float volume_scale = fast_math::exp_f((float)((ret.e_out - e) * (1.0 / 3.0)));
  float S[9] = {expW[0] + 1.f, expW[3], expW[4], expW[3], expW[1] + 1.f, expW[5], expW[4], expW[5], expW[2] + 1.f};
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) S[i] *= volume_scale;
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 9
    for (int j = 0; j < 3; ++j) {
      const float projected_entry = S[3 * i] * F[j] + S[3 * i + 1] * F[3 + j] + S[3 * i + 2] * F[6 + j];
      F_out[3 * i + j] = (ret.projected > 0.f) ? projected_entry : F[3 * i + j];
    }

  const double bulk_term = ((double)m.lambda + (2.0 / 3.0) * mu) * ret.volume;
  const double shear = 2.0 * mu * ret.shear;
  const float t00 = (float)(shear * dev[0] + bulk_term), t11 = (float)(shear * dev[1] + bulk_term),
              t22 = (float)(shear * dev[2] + bulk_term), t01 = (float)(shear * dev[3]),
              t02 = (float)(shear * dev[4]), t12 = (float)(shear * dev[5]);
  tau[0] = t00; tau[1] = t01; tau[2] = t02;
  tau[3] = t01; tau[4] = t11; tau[5] = t12;
  tau[6] = t02; tau[7] = t12; tau[8] = t22;
  return (probe == 0.f) & (y_norm_sq <= kSmallStrainNorm * kSmallStrainNorm) &
         (w_norm_sq <= kSmallStrainNorm * kSmallStrainNorm) & (det > kSmallStrainMinDet) &
         (is_elastic | is_nacc | is_brittle) & (decided > 0.0);
}

}  // namespace fgs
