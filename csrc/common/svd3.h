// Fast, robust 3x3 singular value decomposition F = U diag(sigma) V^T with proper rotations.
//
// Method (double precision throughout; no iteration):
//   1. S = F^T F. Eigenvalues of S in closed form (trigonometric
//      solution of the characteristic cubic of the deviator of S). The eigenvalue that is best
//      separated from the other two (the largest when the deviator's det is >= 0, else the
//      smallest) gets its eigenvector v from the largest cross product of two rows of S - lam I:
//      this is accurate to ~1e-16 / (its gap), and its gap is at least ~1.5x the deviator scale.
//      The other two eigenvectors solve the 2x2 symmetric problem of S in the plane orthogonal
//      to v with one exact Jacobi rotation (stable even for equal eigenvalues, where the
//      directions do not matter). V = [v, w1, w2] is a rotation by construction.
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
// strains of MPM (gaps ~1e-4..1e-3) would put ~1e-4 relative errors into the Kirchhoff stress
// (the float32 tests ask for 1e-5). The speed-up over the previous cyclic Jacobi (up to 30
// sweeps with sqrt and divisions in each rotation) comes from the fixed, short dependency
// chain: one acos, one cos, a handful of sqrt/divisions.
//
// Matrices are row-major [9]: A[3*i + j] = A_ij; the columns of U and V are the singular vectors.
#pragma once
#include <cmath>

#include "hd.h"

namespace fgs {

namespace svd_detail {

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


// Eigenvectors (columns of the proper rotation V, unsorted) of the symmetric S with trace
// tr S > 0: see step 1 of the file comment. A deviator below ~1e-20 tr S (S = tr S I / 3 to
// round-off) gives V = I.
HOST_DEVICE inline void closed_form_eigenvectors(const double s[3][3], double trace, double V[9]) {
  const double m = trace * (1.0 / 3.0);
  const double b00 = s[0][0] - m, b11 = s[1][1] - m, b22 = s[2][2] - m;
  const double o01 = s[0][1], o02 = s[0][2], o12 = s[1][2];
  const double p2 =
      (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (o01 * o01 + o02 * o02 + o12 * o12)) * (1.0 / 6.0);
  double v[3];
  if (!(p2 > 1e-40 * trace * trace)) {
    for (int i = 0; i < 9; ++i) V[i] = (i % 4 == 0) ? 1.0 : 0.0;
    return;
  }
  const double p = sqrt(p2);
  const double detB = b00 * (b11 * b22 - o12 * o12) - o01 * (o01 * b22 - o12 * o02) +
                     o02 * (o01 * o12 - b11 * o02);
  double r = detB / (2.0 * p2 * p);
  r = r > 1.0 ? 1.0 : (r < -1.0 ? -1.0 : r);
  const double phi = acos(r) * (1.0 / 3.0);  // eigenvalues m + 2 p cos(phi + 2 pi k / 3)
  // r >= 0: the largest eigenvalue is the isolated one, else the smallest.
  const double lam = m + 2.0 * p * cos(r >= 0.0 ? phi : phi + 2.0943951023931954923);
  const double r0[3] = {s[0][0] - lam, o01, o02};
  const double r1[3] = {o01, s[1][1] - lam, o12};
  const double r2[3] = {o02, o12, s[2][2] - lam};
  double c01[3], c02[3], c12[3];
  cross3(r0, r1, c01);
  cross3(r0, r2, c02);
  cross3(r1, r2, c12);
  const double n01 = dot3(c01, c01), n02 = dot3(c02, c02), n12 = dot3(c12, c12);
  const double* best = c01;
  double nb = n01;
  if (n02 > nb) { best = c02; nb = n02; }
  if (n12 > nb) { best = c12; nb = n12; }
  const double inv = 1.0 / sqrt(nb);
  for (int i = 0; i < 3; ++i) v[i] = best[i] * inv;
  double e1[3], e2[3];
  any_orthogonal(v, e1);
  cross3(v, e1, e2);
  // 2x2 problem [[a, bb], [bb, c]] in the right-handed basis (v, e1, e2): one exact Jacobi
  // rotation (tan of the smaller angle) diagonalises it.
  double se1[3], se2[3];
  for (int i = 0; i < 3; ++i) {
    se1[i] = s[i][0] * e1[0] + s[i][1] * e1[1] + s[i][2] * e1[2];
    se2[i] = s[i][0] * e2[0] + s[i][1] * e2[1] + s[i][2] * e2[2];
  }
  const double a = dot3(e1, se1), bb = dot3(e1, se2), c = dot3(e2, se2);
  double cs = 1.0, sn = 0.0;
  if (bb != 0.0) {
    const double tau = (c - a) / (2.0 * bb);
    const double t = (tau >= 0.0 ? 1.0 : -1.0) / (fabs(tau) + sqrt(1.0 + tau * tau));
    cs = 1.0 / sqrt(1.0 + t * t);
    sn = t * cs;
  }
  for (int i = 0; i < 3; ++i) {
    V[3 * i + 0] = v[i];
    V[3 * i + 1] = cs * e1[i] - sn * e2[i];
    V[3 * i + 2] = sn * e1[i] + cs * e2[i];
  }
}

}  // namespace svd_detail

// Double-precision SVD (see the file comment). U, V row-major with singular vectors as columns.
HOST_DEVICE inline void svd3(const double F[9], double U[9], double sigma[3], double V[9]) {
  using namespace svd_detail;
  // 1. S = F^T F and its eigenvectors.
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
  s[1][0] = s[0][1];
  s[2][0] = s[0][2];
  s[2][1] = s[1][2];

  closed_form_eigenvectors(s, trace, V);


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
