// Real spherical harmonics of degree 0-3 with the constants and sign conventions of 3DGS,
// the colour of one Gaussian seen from a unit direction (+0.5 offset, clamped at 0), and the
// exact derivatives w.r.t. the coefficients and the direction. Shared by CPU and CUDA.
#pragma once
#include "common/hd.h"

namespace fgs {
namespace raster {

constexpr float kShC0 = 0.28209479177387814f;
constexpr float kShC1 = 0.4886025119029199f;
// Scalars rather than arrays so that device code can use them without __constant__ memory.
constexpr float kShC2_0 = 1.0925484305920792f, kShC2_1 = -1.0925484305920792f,
                kShC2_2 = 0.31539156525252005f, kShC2_3 = -1.0925484305920792f,
                kShC2_4 = 0.5462742152960396f;
constexpr float kShC3_0 = -0.5900435899266435f, kShC3_1 = 2.890611442640554f,
                kShC3_2 = -0.4570457994644658f, kShC3_3 = 0.3731763325901154f,
                kShC3_4 = -0.4570457994644658f, kShC3_5 = 1.445305721320277f,
                kShC3_6 = -0.5900435899266435f;

// Basis values Y[k], k < (degree+1)², at the unit direction (x, y, z).
HOST_DEVICE inline void sh_basis(int degree, float x, float y, float z, float Y[16]) {
  Y[0] = kShC0;
  if (degree < 1) return;
  Y[1] = -kShC1 * y;
  Y[2] = kShC1 * z;
  Y[3] = -kShC1 * x;
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z;
  Y[4] = kShC2_0 * x * y;
  Y[5] = kShC2_1 * y * z;
  Y[6] = kShC2_2 * (2.f * zz - xx - yy);
  Y[7] = kShC2_3 * x * z;
  Y[8] = kShC2_4 * (xx - yy);
  if (degree < 3) return;
  Y[9] = kShC3_0 * y * (3.f * xx - yy);
  Y[10] = kShC3_1 * x * y * z;
  Y[11] = kShC3_2 * y * (4.f * zz - xx - yy);
  Y[12] = kShC3_3 * z * (2.f * zz - 3.f * xx - 3.f * yy);
  Y[13] = kShC3_4 * x * (4.f * zz - xx - yy);
  Y[14] = kShC3_5 * z * (xx - yy);
  Y[15] = kShC3_6 * x * (xx - 3.f * yy);
}

// dir_grad += sum_k w[k] dY_k/d(x, y, z) for the basis at (x, y, z).
HOST_DEVICE inline void sh_basis_backward(int degree, float x, float y, float z, const float w[16],
                                          float dir_grad[3]) {
  if (degree < 1) return;
  float gx = -kShC1 * w[3], gy = -kShC1 * w[1], gz = kShC1 * w[2];
  if (degree >= 2) {
    gx += kShC2_0 * y * w[4] + kShC2_2 * (-2.f * x) * w[6] + kShC2_3 * z * w[7] +
          kShC2_4 * 2.f * x * w[8];
    gy += kShC2_0 * x * w[4] + kShC2_1 * z * w[5] + kShC2_2 * (-2.f * y) * w[6] -
          kShC2_4 * 2.f * y * w[8];
    gz += kShC2_1 * y * w[5] + kShC2_2 * 4.f * z * w[6] + kShC2_3 * x * w[7];
  }
  if (degree >= 3) {
    const float xx = x * x, yy = y * y, zz = z * z;
    gx += kShC3_0 * 6.f * x * y * w[9] + kShC3_1 * y * z * w[10] + kShC3_2 * (-2.f * x * y) * w[11] +
          kShC3_3 * (-6.f * x * z) * w[12] + kShC3_4 * (4.f * zz - 3.f * xx - yy) * w[13] +
          kShC3_5 * 2.f * x * z * w[14] + kShC3_6 * (3.f * xx - 3.f * yy) * w[15];
    gy += kShC3_0 * (3.f * xx - 3.f * yy) * w[9] + kShC3_1 * x * z * w[10] +
          kShC3_2 * (4.f * zz - xx - 3.f * yy) * w[11] + kShC3_3 * (-6.f * y * z) * w[12] +
          kShC3_4 * (-2.f * x * y) * w[13] + kShC3_5 * (-2.f * y * z) * w[14] +
          kShC3_6 * (-6.f * x * y) * w[15];
    gz += kShC3_1 * x * y * w[10] + kShC3_2 * 8.f * y * z * w[11] +
          kShC3_3 * (6.f * zz - 3.f * xx - 3.f * yy) * w[12] + kShC3_4 * 8.f * x * z * w[13] +
          kShC3_5 * (xx - yy) * w[14];
  }
  dir_grad[0] += gx;
  dir_grad[1] += gy;
  dir_grad[2] += gz;
}

// Unit view direction of a Gaussian: normalize(mean - camera_centre), then Rᵀ·dir when a
// per-Gaussian view rotation R (row-major 3x3) is given. Returns |mean - camera_centre|.
HOST_DEVICE inline float sh_view_direction(const float mean[3], const float center[3],
                                           const float* view_rotation, float unit[3], float dir[3]) {
  const float d0 = mean[0] - center[0], d1 = mean[1] - center[1], d2 = mean[2] - center[2];
  float len = sqrtf(d0 * d0 + d1 * d1 + d2 * d2);
  len = len > 1e-12f ? len : 1e-12f;
  unit[0] = d0 / len; unit[1] = d1 / len; unit[2] = d2 / len;
  if (view_rotation) {
    const float* R = view_rotation;
    for (int k = 0; k < 3; ++k) dir[k] = R[k] * unit[0] + R[3 + k] * unit[1] + R[6 + k] * unit[2];
  } else {
    dir[0] = unit[0]; dir[1] = unit[1]; dir[2] = unit[2];
  }
  return len;
}

// RGB of one Gaussian from its coefficients sh[K*3] (K = (degree+1)², channel fastest):
// max(0, sum_k Y_k(dir) sh_k + 0.5).
HOST_DEVICE inline void sh_to_color(int degree, const float* sh, const float dir[3], float rgb[3]) {
  float Y[16];
  sh_basis(degree, dir[0], dir[1], dir[2], Y);
  const int K = (degree + 1) * (degree + 1);
  for (int c = 0; c < 3; ++c) {
    float v = 0.5f;
    for (int k = 0; k < K; ++k) v += Y[k] * sh[3 * k + c];
    rgb[c] = v > 0.f ? v : 0.f;
  }
}

// Backward of sh_view_direction + sh_to_color. drgb: gradient on the clamped colour.
// Writes dsh[K*3]; accumulates into dmean[3]; writes dview_rotation[9] when given.
HOST_DEVICE inline void sh_to_color_backward(int degree, const float* sh, const float mean[3],
                                             const float center[3], const float* view_rotation,
                                             const float drgb[3], float* dsh, float dmean[3],
                                             float* dview_rotation) {
  float unit[3], dir[3];
  const float len = sh_view_direction(mean, center, view_rotation, unit, dir);
  float Y[16];
  sh_basis(degree, dir[0], dir[1], dir[2], Y);
  const int K = (degree + 1) * (degree + 1);
  float g[3];
  for (int c = 0; c < 3; ++c) {
    float v = 0.5f;
    for (int k = 0; k < K; ++k) v += Y[k] * sh[3 * k + c];
    g[c] = v >= 0.f ? drgb[c] : 0.f;  // clamp(min=0) lets the gradient through at 0
  }
  float w[16];
  for (int k = 0; k < K; ++k) {
    for (int c = 0; c < 3; ++c) dsh[3 * k + c] = Y[k] * g[c];
    w[k] = sh[3 * k] * g[0] + sh[3 * k + 1] * g[1] + sh[3 * k + 2] * g[2];
  }
  float ddir[3] = {0.f, 0.f, 0.f};
  sh_basis_backward(degree, dir[0], dir[1], dir[2], w, ddir);
  float dunit[3];
  if (view_rotation) {
    const float* R = view_rotation;
    // dir = Rᵀ unit  =>  dunit = R ddir, dR[m][k] = unit[m] ddir[k]
    for (int m = 0; m < 3; ++m) dunit[m] = R[3 * m] * ddir[0] + R[3 * m + 1] * ddir[1] + R[3 * m + 2] * ddir[2];
    if (dview_rotation)
      for (int m = 0; m < 3; ++m)
        for (int k = 0; k < 3; ++k) dview_rotation[3 * m + k] = unit[m] * ddir[k];
  } else {
    dunit[0] = ddir[0]; dunit[1] = ddir[1]; dunit[2] = ddir[2];
  }
  const float proj = unit[0] * dunit[0] + unit[1] * dunit[1] + unit[2] * dunit[2];
  for (int k = 0; k < 3; ++k) dmean[k] += (dunit[k] - unit[k] * proj) / len;
}

}  // namespace raster
}  // namespace fgs
