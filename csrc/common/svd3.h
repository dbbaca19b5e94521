// Fast, robust 3x3 singular value decomposition F = U diag(sigma) V^T with proper rotations.
//
// Method (after McAdams et al. 2011, "Computing the SVD of 3x3 matrices with minimal branching
// and elementary floating point operations"; written from the algorithm, in double):
//   1. S = F^T F / tr(F^T F) (scale-free). Cyclic Jacobi on S with *approximate* Givens
//      rotations: for the (p, q) block the half-angle pair (ch, sh) = (2 (s_pp - s_qq), s_pq)
//      is the first-order Jacobi angle (exact to third order near convergence), clamped to the
//      exact maximum angle pi/4 (half-angle pi/8) when the first-order formula is not valid.
//      (ch, sh) is normalised with a ~12-bit reciprocal square root only: a rotation scaled by
//      (1 + eta) just scales S by (1 + eta)^2, which leaves its eigenvectors alone, so no
//      accuracy is lost and the dependency chain of a rotation holds no sqrt or division.
//      The rotations are accumulated as a quaternion (V is built, exactly orthonormal, at the
//      end). Four sweeps, then further sweeps only while an off-diagonal entry is above 1e-15
//      (relative to tr S) -- rarely more than one extra sweep.
//   2. B = F V; its columns are sorted by decreasing norm, swapping with one sign flip so that
//      det V stays +1.
//   3. Gram-Schmidt QR of B: u1 = b1/|b1|, u2 = normalised (b2 - (u1.b2) u1), u3 = u1 x u2,
//      sigma = diag(R): sigma1 = |b1|, sigma2 = |b2 - (u1.b2) u1|, sigma3 = u3 . b3.
// U = [u1 u2 u3] is a rotation by construction and sigma3 carries the sign of det F, so
// det U = det V = +1 and sigma1 >= sigma2 >= |sigma3| (sigma3 < 0 iff det F < 0).
// The diagonal of R is second-order accurate in the error of V, so the singular values come out
// at double precision (~1e-16 |F|) even for nearly singular F; rank-deficient cases complete U
// with an arbitrary orthonormal direction (exact: the corresponding sigma is ~0).
//
// Why double and not float: scalar float and double arithmetic cost the same on the CPU, and
// float eigenvectors of F^T F are off by ~1e-7 / (relative eigen-gap), which for the small
// strains of MPM (gaps ~1e-3) would put ~1e-4 relative errors into the Kirchhoff stress.
// The speed comes from the branch-free approximate rotations, the fixed sweep count, one
// reciprocal-sqrt approximation per rotation and no division or sqrt inside the iteration.
//
// Matrices are row-major [9]: A[3*i + j] = A_ij; the columns of U and V are the singular vectors.
#pragma once
#include <cmath>

#include "common/hd.h"

#if !defined(__CUDA_ARCH__) && (defined(__SSE__) || defined(__x86_64__))
#include <immintrin.h>
#define FGS_SVD_HAVE_SSE_RSQRT 1
#endif

namespace fgs {

namespace svd_detail {

// ~12-bit accurate 1/sqrt(x) for normal positive float x (the Jacobi rotations only need an
// approximately unit (ch, sh); see the file comment).
HOST_DEVICE inline float approx_rsqrt(float x) {
#if defined(__CUDA_ARCH__)
  return rsqrtf(x);
#elif defined(FGS_SVD_HAVE_SSE_RSQRT)
  return _mm_cvtss_f32(_mm_rsqrt_ss(_mm_set_ss(x)));
#else
  return 1.0f / sqrtf(x);
#endif
}

// Unit quaternion (w, x, y, z) of the accumulated right rotation V (not normalised).
struct Quat {
  double w, x, y, z;
};

// One approximate Jacobi rotation in the (p, q) plane (k = the third index, (p, q, k) cyclic)
// of the symmetric S, stored as its 6 entries s[p][q]; V <- V G (quaternion q <- q * g).
// G = rho R, R rotates e_p toward e_q by theta (axis +e_k), rho ~ 1; S <- G^T S G.
template <int P, int Q, int K>
HOST_DEVICE inline void approx_jacobi(double s[3][3], Quat& quat) {
  constexpr double kGamma = 5.828427124746190;      // (1 + sqrt 2)^2 = 1 / tan^2(pi/8)
  constexpr double kCosPi8 = 0.923879532511286756;  // cos(pi/8)
  constexpr double kSinPi8 = 0.382683432365089772;  // sin(pi/8)
  const double spp = s[P][P], sqq = s[Q][Q], spq = s[P][Q];
  double ch = 2.0 * (spp - sqq);
  double sh = spq;
  // First-order half angle atan(sh / ch) is only valid below pi/8; beyond, rotate by pi/4.
  const bool small_angle = kGamma * sh * sh < ch * ch;
  if (!small_angle) {
    ch = kCosPi8;
    sh = kSinPi8;
  }
  // Negligible off-diagonal (also keeps ch^2 + sh^2 a normal float): identity rotation.
  if (sh * sh < 1e-36) {
    ch = 1.0;
    sh = 0.0;
  }
  // Approximate normalisation: |(ch, sh)|^2 = rho = 1 +- ~1e-3 (see the file comment).
  const double omega = approx_rsqrt(static_cast<float>(ch * ch + sh * sh));
  ch *= omega;
  sh *= omega;
  const double c = ch * ch - sh * sh;  // rho cos(theta)
  const double sn = 2.0 * ch * sh;     // rho sin(theta)
  const double rho = ch * ch + sh * sh;  // |G| = rho ~ 1; S scales by rho^2
  const double rho2 = rho * rho;
  const double cc = c * c, ss = sn * sn, cs = c * sn;
  // 2x2 block.
  s[P][P] = cc * spp + 2.0 * cs * spq + ss * sqq;
  s[Q][Q] = ss * spp - 2.0 * cs * spq + cc * sqq;
  s[P][Q] = (cc - ss) * spq - cs * (spp - sqq);
  s[Q][P] = s[P][Q];
  // Couplings to k and the untouched diagonal entry (scaled like the rest).
  const double skp = s[K][P], skq = s[K][Q];
  s[K][P] = rho * (c * skp + sn * skq);
  s[K][Q] = rho * (c * skq - sn * skp);
  s[P][K] = s[K][P];
  s[Q][K] = s[K][Q];
  s[K][K] *= rho2;
  // quat <- quat * (ch, sh e_k).
  const Quat a = quat;
  if (K == 2) {
    quat.w = a.w * ch - a.z * sh;
    quat.x = a.x * ch + a.y * sh;
    quat.y = a.y * ch - a.x * sh;
    quat.z = a.z * ch + a.w * sh;
  } else if (K == 0) {
    quat.w = a.w * ch - a.x * sh;
    quat.x = a.x * ch + a.w * sh;
    quat.y = a.y * ch + a.z * sh;
    quat.z = a.z * ch - a.y * sh;
  } else {
    quat.w = a.w * ch - a.y * sh;
    quat.x = a.x * ch - a.z * sh;
    quat.y = a.y * ch + a.w * sh;
    quat.z = a.z * ch + a.x * sh;
  }
}

// Rotation matrix (row-major) of the non-zero quaternion q (normalised here).
HOST_DEVICE inline void quat_to_matrix(const Quat& q, double R[9]) {
  const double n = q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z;
  const double t = 2.0 / n;
  const double xx = t * q.x * q.x, yy = t * q.y * q.y, zz = t * q.z * q.z;
  const double xy = t * q.x * q.y, xz = t * q.x * q.z, yz = t * q.y * q.z;
  const double wx = t * q.w * q.x, wy = t * q.w * q.y, wz = t * q.w * q.z;
  R[0] = 1.0 - yy - zz; R[1] = xy - wz;       R[2] = xz + wy;
  R[3] = xy + wz;       R[4] = 1.0 - xx - zz; R[5] = yz - wx;
  R[6] = xz - wy;       R[7] = yz + wx;       R[8] = 1.0 - xx - yy;
}

HOST_DEVICE inline double dot3(const double* a, const double* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

HOST_DEVICE inline void cross3(const double* a, const double* b, double* c) {
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
}

// A unit vector orthogonal to the unit vector u (cross product with the least aligned axis).
HOST_DEVICE inline void any_orthogonal(const double* u, double* w) {
  const double ax = fabs(u[0]), ay = fabs(u[1]), az = fabs(u[2]);
  double e[3] = {0.0, 0.0, 0.0};
  if (ax <= ay && ax <= az) e[0] = 1.0;
  else if (ay <= az) e[1] = 1.0;
  else e[2] = 1.0;
  cross3(u, e, w);
  const double inv = 1.0 / sqrt(dot3(w, w));
  w[0] *= inv; w[1] *= inv; w[2] *= inv;
}

// If column j of B is longer than column i (i < j): swap them, negating the new column j (of
// B and V alike) so that det V is unchanged.
HOST_DEVICE inline void sort_pair(double b[3][3], double V[9], double norm2[3], int i, int j) {
  if (norm2[i] < norm2[j]) {
    for (int r = 0; r < 3; ++r) {
      const double bi = b[i][r];
      b[i][r] = b[j][r];
      b[j][r] = -bi;
      const double vi = V[3 * r + i];
      V[3 * r + i] = V[3 * r + j];
      V[3 * r + j] = -vi;
    }
    const double t = norm2[i];
    norm2[i] = norm2[j];
    norm2[j] = t;
  }
}

}  // namespace svd_detail

// Double-precision SVD (see the file comment). U, V row-major with singular vectors as columns.
HOST_DEVICE inline void svd3(const double F[9], double U[9], double sigma[3], double V[9]) {
  using namespace svd_detail;
  // 1. S = F^T F, normalised by its trace.
  double s[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = i; j < 3; ++j) s[i][j] = F[i] * F[j] + F[3 + i] * F[3 + j] + F[6 + i] * F[6 + j];
  const double trace = s[0][0] + s[1][1] + s[2][2];
  if (!(trace > 0.0) || !(trace < 1e300)) {  // zero matrix or non-finite input
    for (int i = 0; i < 9; ++i) {
      U[i] = (i % 4 == 0) ? 1.0 : 0.0;
      V[i] = U[i];
    }
    const double z = (trace == 0.0) ? 0.0 : NAN;
    sigma[0] = z; sigma[1] = z; sigma[2] = z;
    return;
  }
  const double inv_trace = 1.0 / trace;
  for (int i = 0; i < 3; ++i)
    for (int j = i; j < 3; ++j) {
      s[i][j] *= inv_trace;
      s[j][i] = s[i][j];
    }

  Quat quat{1.0, 0.0, 0.0, 0.0};
  for (int sweep = 0; sweep < 12; ++sweep) {
    approx_jacobi<0, 1, 2>(s, quat);
    approx_jacobi<1, 2, 0>(s, quat);
    approx_jacobi<2, 0, 1>(s, quat);
    // S is scaled by ~(1 +- 1e-3) per rotation: measure against its current trace.
    const double tr = s[0][0] + s[1][1] + s[2][2];
    if (sweep >= 2) {
      // Converged when the off-diagonal is below 1e-8 of the deviatoric part of S (the
      // eigenvectors are then good to ~1e-8 of what matters for stress and reconstruction)
      // and every s_pq is below 1e-8 sqrt(s_pp s_qq) (keeps the directions of tiny singular
      // values accurate), or when it is at the round-off level 1e-15 tr S.
      const double s01 = s[0][1] * s[0][1], s12 = s[1][2] * s[1][2], s02 = s[0][2] * s[0][2];
      const double off = s01 + s12 + s02;
      const double m = tr * (1.0 / 3.0);
      const double dev = (s[0][0] - m) * (s[0][0] - m) + (s[1][1] - m) * (s[1][1] - m) +
                         (s[2][2] - m) * (s[2][2] - m);
      const bool relative = off <= 1e-16 * dev && s01 <= 1e-16 * s[0][0] * s[1][1] &&
                            s12 <= 1e-16 * s[1][1] * s[2][2] && s02 <= 1e-16 * s[0][0] * s[2][2];
      if (relative || off <= 1e-30 * tr * tr) break;
    }
  }
  quat_to_matrix(quat, V);

  // 2. B = F V (b[j] = column j), columns sorted by decreasing norm.
  double b[3][3];
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i)
      b[j][i] = F[3 * i] * V[j] + F[3 * i + 1] * V[3 + j] + F[3 * i + 2] * V[6 + j];
  double norm2[3] = {dot3(b[0], b[0]), dot3(b[1], b[1]), dot3(b[2], b[2])};
  sort_pair(b, V, norm2, 0, 1);
  sort_pair(b, V, norm2, 0, 2);
  sort_pair(b, V, norm2, 1, 2);

  // 3. Gram-Schmidt QR of B.
  const double tiny2 = 1e-60 * trace;  // below this a column is numerically zero
  double u1[3], u2[3], u3[3];
  const double n1 = sqrt(norm2[0]);
  {
    const double inv = 1.0 / n1;  // n1^2 >= trace / 3 > 0
    for (int i = 0; i < 3; ++i) u1[i] = b[0][i] * inv;
  }
  double w[3] = {b[1][0], b[1][1], b[1][2]};
  {
    const double d = dot3(u1, w);
    for (int i = 0; i < 3; ++i) w[i] -= d * u1[i];
  }
  const double w2 = dot3(w, w);
  double n2 = 0.0;
  if (w2 > tiny2) {
    n2 = sqrt(w2);
    const double inv = 1.0 / n2;
    for (int i = 0; i < 3; ++i) u2[i] = w[i] * inv;
  } else {
    any_orthogonal(u1, u2);
  }
  cross3(u1, u2, u3);
  sigma[0] = n1;
  sigma[1] = n2;
  sigma[2] = dot3(u3, b[2]);
  for (int i = 0; i < 3; ++i) {
    U[3 * i + 0] = u1[i];
    U[3 * i + 1] = u2[i];
    U[3 * i + 2] = u3[i];
  }
}

// Float interface: float32 in/out, computed in double.
HOST_DEVICE inline void svd3(const float F[9], float U[9], float sigma[3], float V[9]) {
  double Fd[9], Ud[9], sd[3], Vd[9];
  for (int i = 0; i < 9; ++i) Fd[i] = static_cast<double>(F[i]);
  svd3(Fd, Ud, sd, Vd);
  for (int i = 0; i < 9; ++i) {
    U[i] = static_cast<float>(Ud[i]);
    V[i] = static_cast<float>(Vd[i]);
  }
  for (int i = 0; i < 3; ++i) sigma[i] = static_cast<float>(sd[i]);
}

}  // namespace fgs
