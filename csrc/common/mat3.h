// Small 3-vector / 3x3-matrix helpers (row-major float[9]) shared by the CPU and CUDA kernels.
#pragma once
#include <cmath>

#include "common/hd.h"

namespace fgs {

HOST_DEVICE inline void mat3_identity(float A[9]) {
  for (int i = 0; i < 9; ++i) A[i] = (i % 4 == 0) ? 1.f : 0.f;
}

HOST_DEVICE inline void mat3_copy(const float* A, float* B) {
  for (int i = 0; i < 9; ++i) B[i] = A[i];
}

// C = A * B
HOST_DEVICE inline void mat3_mul(const float* A, const float* B, float* C) {
  float R[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
  for (int i = 0; i < 9; ++i) C[i] = R[i];
}

// C = A * B^T
HOST_DEVICE inline void mat3_mul_bt(const float* A, const float* B, float* C) {
  float R[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = A[3 * i] * B[3 * j] + A[3 * i + 1] * B[3 * j + 1] + A[3 * i + 2] * B[3 * j + 2];
  for (int i = 0; i < 9; ++i) C[i] = R[i];
}

// C = A^T * B
HOST_DEVICE inline void mat3_mul_at(const float* A, const float* B, float* C) {
  float R[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = A[i] * B[j] + A[3 + i] * B[3 + j] + A[6 + i] * B[6 + j];
  for (int i = 0; i < 9; ++i) C[i] = R[i];
}

HOST_DEVICE inline void mat3_transpose(const float* A, float* B) {
  float R[9] = {A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8]};
  for (int i = 0; i < 9; ++i) B[i] = R[i];
}

HOST_DEVICE inline float mat3_det(const float* A) {
  return A[0] * (A[4] * A[8] - A[5] * A[7]) - A[1] * (A[3] * A[8] - A[5] * A[6]) +
         A[2] * (A[3] * A[7] - A[4] * A[6]);
}

HOST_DEVICE inline void mat3_vec(const float* A, const float* x, float* y) {
  float r0 = A[0] * x[0] + A[1] * x[1] + A[2] * x[2];
  float r1 = A[3] * x[0] + A[4] * x[1] + A[5] * x[2];
  float r2 = A[6] * x[0] + A[7] * x[1] + A[8] * x[2];
  y[0] = r0; y[1] = r1; y[2] = r2;
}

HOST_DEVICE inline float vec3_dot(const float* a, const float* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

HOST_DEVICE inline float vec3_norm(const float* a) { return sqrtf(vec3_dot(a, a)); }

}  // namespace fgs
