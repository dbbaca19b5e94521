// The constitutive update of csrc/common/constitutive.h without an SVD: float32, branch-free,
// written so that GCC vectorises a loop over particles that calls it (the CPU kernels run
// it 8 or 16 particles per instruction; see csrc/mpm/constitutive_batch.h).
//
// Every model is isotropic, so the stress and the return map only need the eigen-decomposition of
// the left Cauchy-Green tensor b = F F^T = Q diag(s) Q^T, s_i = sigma_i^2, and the model's law
// (csrc/common/material_registry.h) only the strain invariants:
//   Hencky strain   eps_i = ln sigma_i = 1/2 log1p(|Q_i^T F|^2 - 1),  Q = eigenvectors of b - I
//   Kirchhoff       tau = Q diag(tau_i) Q^T, tau_i the law's principal stresses
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

// What the return map did to one particle, for projected_deformation: F_E = Q diag(exp(log_
// stretch_i)) Q^T F / |Q_i|^2 where `projected` is non-zero, F itself elsewhere.
struct EigProjection {
  double Q[9];             // eigenvectors of b (columns, orthogonal to float precision)
  double log_stretch[3];   // eps_out_i - eps_i
  float projected;         // 1 if the law changed F, else 0
};

// The constitutive update through the eigen-decomposition of b, first half: the law's decisions,
// the new state and the Kirchhoff stress of F_E. F: F_trial; state: in/out (kMaxStateFields floats);
// tau: Kirchhoff stress of F_E; proj: what projected_deformation needs to form F_E; dissipated: the
// energy per unit rest volume the update took (the law's `dissipated`).
// Returns false (outputs meaningless) where the caller must use constitutive_update instead:
// see the file comment. Laws: MaterialModels, or OneModel<Model> where every row has that model.
template <class Laws = MaterialModels>
HOST_DEVICE FGS_FORCE_INLINE bool constitutive_stress_eig(const MaterialRow& m, const float F[9],
                                                          float state[kMaxStateFields], float tau[9],
                                                          EigProjection* proj, float* dissipated) {
  double Fd[9], b[6];
  const double det = cauchy_green_minus_identity(F, Fd, b);
  double Q[9];
  sym3_eigenvectors(b, Q);

  float probe = state[0] * 0.f;  // NaN/Inf anywhere in the input makes it non-zero
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
  // Bitwise & and | (no short circuit) on the conditions: branches would stop the vectoriser.
  const bool valid = (probe == 0.f) & (det > 0.0) & (stretch_sq_min > (double)kEigMinStretchSq) &
                     Laws::known(m);

  // From here on double (the loop stays vectorised, 4 lanes per instruction): in float a return
  // map lands ~1e-5 K^2 off its yield surface for strains of order 1, where the yield function is
  // a small difference of large terms.
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
  const double dev_max = fast_math::max_of(fast_math::max_of(dev[0], dev[1]), dev[2]);
  const StrainInvariants s{e, 1.0 / (det > 0.0 ? det : 1.0), dev_norm, dev_max, 0.0};
  const LawResult ret = Laws::update(m, state, s);
  proj->projected = ret.projected;
#pragma GCC unroll 9
  for (int i = 0; i < 9; ++i) proj->Q[i] = Q[i];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) proj->log_stretch[i] = (ret.dev_scale - 1.0) * dev[i] + (ret.e_out - e) * (1.0 / 3.0);
  // tau = Q diag(tau_i) Q^T with the law's principal stresses.
  double d[3];
#pragma GCC unroll 9
  for (int i = 0; i < 3; ++i) d[i] = Laws::principal_stress(m, ret, dev[i], e);
  *dissipated = (float)Laws::dissipated(m, state, ret, dev, e);
#pragma GCC unroll 9
  for (int k = 0; k < kMaxStateFields; ++k) state[k] = ret.state[k];
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
// products are well scaled), the law's algebra in double. States within the float error of
// |dev eps| of a law's threshold are left to the eigen path, so both paths decide alike.

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
// F_out: F_E; state in/out (kMaxStateFields floats); tau: Kirchhoff stress of F_E. Returns false
// (outputs meaningless) where the caller must run the eigen path (constitutive_stress_eig)
// instead: isochoric strains beyond kSmallStrainNorm, a state the law does not decide (within
// float error of a threshold, a non-linear stress, dissipation), or anything the eigen path rejects.
// Where it returns true the update dissipated nothing. Laws as for constitutive_stress_eig.
template <class Laws = MaterialModels>
HOST_DEVICE FGS_FORCE_INLINE bool constitutive_small_strain(const MaterialRow& m, const float F[9],
                                                            float state[kMaxStateFields], float F_out[9],
                                                            float tau[9]) {
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
  float probe = state[0] * 0.f;  // NaN/Inf anywhere in the input makes it non-zero
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

  // The largest eigenvalue of a traceless symmetric matrix is at most sqrt(2/3) of its norm: a
  // driving stress computed from that bound is an upper bound of the true one. The float error of
  // |dev eps| is a few ulp of |eps_iso| <= 1.03 |Y|: a law leaves a state closer than that to one of
  // its thresholds to the eigen path (LawResult::decided).
  const StrainInvariants invariants{e, 1.0 / (det > 0.0 ? det : 1.0), dev_norm, 0.81649658092772603273 * dev_norm,
                                    2e-6 * (double)sqrtf(y_norm_sq) + 1e-12};
  const LawResult ret = Laws::update(m, state, invariants);
#pragma GCC unroll 9
  for (int k = 0; k < kMaxStateFields; ++k) state[k] = ret.state[k];

  // exp(W) = I + W P, P = sum_k W^(k-1) / k! for k = 1..6, by Horner; W = (g - 1) dev eps.
  float W[6];
#pragma GCC unroll 6
  for (int i = 0; i < 6; ++i) W[i] = (float)((ret.dev_scale - 1.0) * dev[i]);
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

  // The linear stress (a state the law decided has one: see LawResult::decided).
  const double mu = m.mu;
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
         Laws::known(m) & (ret.decided > 0.0);
}

}  // namespace fgs
