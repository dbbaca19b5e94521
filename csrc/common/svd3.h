// Robust 3x3 singular value decomposition F = U diag(sigma) V^T with proper rotations.
//
// Method (computed in double, also on the GPU: it is a few hundred flops per matrix):
//   1. cyclic Jacobi eigen-decomposition of the symmetric A = F^T F  ->  V (columns = right
//      singular vectors), eigenvalues sorted in decreasing order, det V forced to +1;
//   2. B = F V, then a Gram-Schmidt QR of B (with one re-orthogonalisation pass):
//      u1 = b1/|b1|, u2 = orthonormalised b2, u3 = u1 x u2, and sigma = diag(R):
//      sigma1 = |b1|, sigma2 = |b2 - (u1.b2) u1|, sigma3 = u3 . b3.
// U = [u1 u2 u3] is then a rotation by construction and sigma3 carries the sign of det F, so
// det U = det V = +1 and sigma1 >= sigma2 >= |sigma3| (sigma3 < 0 iff det F < 0).
// Taking the small singular values from the QR of F V (instead of sqrt of the eigenvalues of
// F^T F) keeps them accurate to ~1e-16 |F| even for nearly singular F. Rank-deficient cases
// (|b1| or the orthogonal part of b2 at the round-off level) complete U with an arbitrary
// orthonormal direction, which is exact because the corresponding sigma is ~0.
//
// Matrices are row-major [9]: A[3*i + j] = A_ij; the columns of U and V are the singular vectors.
#pragma once
#include <cmath>

#include "common/hd.h"

namespace fgs {

namespace svd_detail {

// One Jacobi rotation in the (p, q) plane that zeroes A_pq of the symmetric A; V <- V J.
HOST_DEVICE inline void jacobi_rotate(double A[9], double V[9], int p, int q) {
  const double apq = A[3 * p + q];
  if (apq == 0.0) return;
  const double app = A[3 * p + p], aqq = A[3 * q + q];
  const double theta = (aqq - app) / (2.0 * apq);
  // t = tan of the rotation angle, the smaller root of t^2 + 2 t theta - 1 = 0.
  double t;
  if (fabs(theta) > 1e150) {
    t = 0.5 / theta;
  } else {
    t = (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
  }
  const double c = 1.0 / sqrt(t * t + 1.0);
  const double s = t * c;
  // A <- J^T A J with J = identity except J_pp = J_qq = c, J_pq = s, J_qp = -s.
  // Columns p, q first (A J), then rows p, q (J^T (A J)).
  for (int k = 0; k < 3; ++k) {
    const double akp = A[3 * k + p], akq = A[3 * k + q];
    A[3 * k + p] = c * akp - s * akq;
    A[3 * k + q] = s * akp + c * akq;
  }
  for (int k = 0; k < 3; ++k) {
    const double apk = A[3 * p + k], aqk = A[3 * q + k];
    A[3 * p + k] = c * apk - s * aqk;
    A[3 * q + k] = s * apk + c * aqk;
  }
  A[3 * p + q] = 0.0;  // exact by construction; remove the round-off residue
  A[3 * q + p] = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double vkp = V[3 * k + p], vkq = V[3 * k + q];
    V[3 * k + p] = c * vkp - s * vkq;
    V[3 * k + q] = s * vkp + c * vkq;
  }
}

HOST_DEVICE inline void swap_columns(double V[9], int a, int b) {
  for (int k = 0; k < 3; ++k) {
    const double tmp = V[3 * k + a];
    V[3 * k + a] = V[3 * k + b];
    V[3 * k + b] = tmp;
  }
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
  const double n = sqrt(dot3(w, w));
  w[0] /= n; w[1] /= n; w[2] /= n;
}

}  // namespace svd_detail

// Double-precision SVD (see the file comment). U, V row-major with singular vectors as columns.
HOST_DEVICE inline void svd3(const double F[9], double U[9], double sigma[3], double V[9]) {
  using namespace svd_detail;
  double fnorm2 = 0.0;
  for (int i = 0; i < 9; ++i) fnorm2 += F[i] * F[i];
  for (int i = 0; i < 9; ++i) {
    U[i] = (i % 4 == 0) ? 1.0 : 0.0;
    V[i] = U[i];
  }
  if (!(fnorm2 > 0.0)) {  // zero matrix (or NaN input): sigma = 0 / NaN, identity rotations
    const double z = (fnorm2 == 0.0) ? 0.0 : fnorm2;
    sigma[0] = z; sigma[1] = z; sigma[2] = z;
    return;
  }

  // 1. Jacobi on A = F^T F.
  double A[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      A[3 * i + j] = F[i] * F[j] + F[3 + i] * F[3 + j] + F[6 + i] * F[6 + j];
  const double tiny_offdiag = 1e-40 * fnorm2;  // absolute floor, relative to the scale of A
  for (int sweep = 0; sweep < 30; ++sweep) {
    // Converged when every off-diagonal entry is negligible against its diagonal pair
    // (relative criterion: keeps the small eigen-directions accurate).
    bool converged = true;
    const int P[3] = {0, 0, 1}, Q[3] = {1, 2, 2};
    for (int r = 0; r < 3; ++r) {
      const double apq = fabs(A[3 * P[r] + Q[r]]);
      const double scale = sqrt(fabs(A[3 * P[r] + P[r]] * A[3 * Q[r] + Q[r]]));
      if (apq > 1e-17 * scale && apq > tiny_offdiag) converged = false;
    }
    if (converged) break;
    for (int r = 0; r < 3; ++r) jacobi_rotate(A, V, P[r], Q[r]);
  }

  // Sort eigenvalues (diagonal of A) in decreasing order, permuting the columns of V.
  double lam[3] = {A[0], A[4], A[8]};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2 - i; ++j)
      if (lam[j] < lam[j + 1]) {
        const double tmp = lam[j]; lam[j] = lam[j + 1]; lam[j + 1] = tmp;
        swap_columns(V, j, j + 1);
      }
  // Proper rotation: det V = +1 (flip the last column if needed).
  const double detV = V[0] * (V[4] * V[8] - V[5] * V[7]) - V[1] * (V[3] * V[8] - V[5] * V[6]) +
                      V[2] * (V[3] * V[7] - V[4] * V[6]);
  if (detV < 0.0) {
    V[2] = -V[2]; V[5] = -V[5]; V[8] = -V[8];
  }

  // 2. B = F V (columns b_j = F v_j), Gram-Schmidt QR of B.
  double b[3][3];  // b[j] = column j of B
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i)
      b[j][i] = F[3 * i] * V[j] + F[3 * i + 1] * V[3 + j] + F[3 * i + 2] * V[6 + j];

  const double tiny = 1e-30 * sqrt(fnorm2);  // below this a column is numerically zero
  double u1[3], u2[3], u3[3];
  const double n1 = sqrt(dot3(b[0], b[0]));
  if (n1 > tiny) {
    for (int i = 0; i < 3; ++i) u1[i] = b[0][i] / n1;
  } else {
    u1[0] = 1.0; u1[1] = 0.0; u1[2] = 0.0;
  }
  double w[3] = {b[1][0], b[1][1], b[1][2]};
  for (int pass = 0; pass < 2; ++pass) {  // "twice is enough" re-orthogonalisation
    const double d = dot3(u1, w);
    for (int i = 0; i < 3; ++i) w[i] -= d * u1[i];
  }
  const double n2 = sqrt(dot3(w, w));
  if (n2 > tiny) {
    for (int i = 0; i < 3; ++i) u2[i] = w[i] / n2;
  } else {
    any_orthogonal(u1, u2);
  }
  cross3(u1, u2, u3);
  sigma[0] = (n1 > tiny) ? n1 : 0.0;
  sigma[1] = (n2 > tiny) ? n2 : 0.0;
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
