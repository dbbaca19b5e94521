// Per-Gaussian math of the rasterizer (docs/formulas.md §11), shared by the CPU and CUDA kernels:
// covariance from scale + quaternion, EWA projection to the image plane, conic, screen
// support, and the exact derivatives of each step. Every function works on one Gaussian.
#pragma once
#include <cmath>

#include "common/hd.h"
#include "common/mat3.h"

namespace fgs {
namespace raster {

constexpr int kTileSize = 16;
constexpr float kLowPass = 0.3f;           // px² added to the 2D covariance diagonal
constexpr float kAlphaMin = 1.0f / 255.0f;  // contributions below this are skipped
constexpr float kAlphaMax = 0.99f;          // alpha is clamped to this
constexpr float kTransmittanceMin = 1e-4f;  // a pixel stops once T would fall below this
constexpr float kFrustumSlack = 0.3f;       // Jacobian clamp margin (x/z, y/z), as in 3DGS

// The camera as plain numbers: world-to-camera rotation R (row-major) and translation t.
struct CameraParams {
  float R[9];
  float t[3];
  float center[3];  // camera position in world coordinates (for SH view directions)
  float fx, fy, cx, cy;
  int width, height;
  float near_plane;
};

// True for a finite float (no NaN / Inf); written out so it means the same on host and device.
HOST_DEVICE inline bool is_finite(float v) { return v == v && fabsf(v) <= 3.402823466e38f; }

// Rotation matrix (row-major) of a unit quaternion q = (w, x, y, z).
HOST_DEVICE inline void quat_to_rotation(const float q[4], float R[9]) {
  const float w = q[0], x = q[1], y = q[2], z = q[3];
  R[0] = 1.f - 2.f * (y * y + z * z); R[1] = 2.f * (x * y - w * z); R[2] = 2.f * (x * z + w * y);
  R[3] = 2.f * (x * y + w * z); R[4] = 1.f - 2.f * (x * x + z * z); R[5] = 2.f * (y * z - w * x);
  R[6] = 2.f * (x * z - w * y); R[7] = 2.f * (y * z + w * x); R[8] = 1.f - 2.f * (x * x + y * y);
}

// Normalise a quaternion; a zero quaternion stays zero (its rotation is then the identity).
HOST_DEVICE inline float quat_normalize(const float q[4], float qn[4]) {
  float norm = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  norm = norm > 1e-12f ? norm : 1e-12f;
  for (int i = 0; i < 4; ++i) qn[i] = q[i] / norm;
  return norm;
}

// Sigma = R diag(s)² Rᵀ with R the rotation of the normalised quaternion.
HOST_DEVICE inline void scale_quat_to_covariance(const float s[3], const float q[4], float Sigma[9]) {
  float qn[4], R[9], M[9];
  quat_normalize(q, qn);
  quat_to_rotation(qn, R);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) M[3 * i + j] = R[3 * i + j] * s[j];
  mat3_mul_bt(M, M, Sigma);
}

// Backward of scale_quat_to_covariance: dSigma (full 3x3, not assumed symmetric) -> ds, dq.
HOST_DEVICE inline void scale_quat_to_covariance_backward(const float s[3], const float q[4],
                                                          const float dSigma[9], float ds[3],
                                                          float dq[4]) {
  float qn[4], R[9], M[9], dM[9], dR[9];
  const float norm = quat_normalize(q, qn);
  quat_to_rotation(qn, R);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) M[3 * i + j] = R[3 * i + j] * s[j];
  // Sigma = M Mᵀ  =>  dM = (dSigma + dSigmaᵀ) M
  float G[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) G[3 * i + j] = dSigma[3 * i + j] + dSigma[3 * j + i];
  mat3_mul(G, M, dM);
  for (int j = 0; j < 3; ++j)
    ds[j] = dM[j] * R[j] + dM[3 + j] * R[3 + j] + dM[6 + j] * R[6 + j];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) dR[3 * i + j] = dM[3 * i + j] * s[j];
  const float w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  float dqn[4];
  dqn[0] = 2.f * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
  dqn[1] = 2.f * (y * dR[1] + z * dR[2] + y * dR[3] - 2.f * x * dR[4] - w * dR[5] + z * dR[6] +
                  w * dR[7] - 2.f * x * dR[8]);
  dqn[2] = 2.f * (-2.f * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] +
                  z * dR[7] - 2.f * y * dR[8]);
  dqn[3] = 2.f * (-2.f * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - 2.f * z * dR[4] +
                  y * dR[5] + x * dR[6] + y * dR[7]);
  // qn = q / |q|  =>  dq = (dqn - qn (qn·dqn)) / |q|
  const float proj = qn[0] * dqn[0] + qn[1] * dqn[1] + qn[2] * dqn[2] + qn[3] * dqn[3];
  for (int i = 0; i < 4; ++i) dq[i] = (dqn[i] - qn[i] * proj) / norm;
}

// Result of projecting one Gaussian.
struct Projected {
  float cam[3];     // camera-space mean
  float mean2d[2];  // pixel coordinates of the mean
  float cov2d[3];   // (a, b, c): 2D covariance incl. low-pass, [[a, b], [b, c]]
  float conic[3];   // inverse of cov2d: (A, B, C)
  float det;        // determinant of cov2d
};

// The clamped x/z used in the Jacobian (3DGS: 1.3 × half field of view, per side).
HOST_DEVICE inline float clamp_ratio(float r, float lo, float hi) {
  return r < lo ? lo : (r > hi ? hi : r);
}

HOST_DEVICE inline void jacobian_limits(const CameraParams& cam, float lim[4]) {
  const float tan_x = 0.5f * cam.width / cam.fx, tan_y = 0.5f * cam.height / cam.fy;
  lim[0] = -(cam.cx / cam.fx + kFrustumSlack * tan_x);                // x/z min
  lim[1] = (cam.width - cam.cx) / cam.fx + kFrustumSlack * tan_x;     // x/z max
  lim[2] = -(cam.cy / cam.fy + kFrustumSlack * tan_y);                // y/z min
  lim[3] = (cam.height - cam.cy) / cam.fy + kFrustumSlack * tan_y;    // y/z max
}

// T = J W (2x3, row-major) for camera-space point p.
HOST_DEVICE inline void projection_jacobian(const CameraParams& cam, const float p[3], float T[6]) {
  float lim[4];
  jacobian_limits(cam, lim);
  const float z = p[2];
  const float tx = z * clamp_ratio(p[0] / z, lim[0], lim[1]);
  const float ty = z * clamp_ratio(p[1] / z, lim[2], lim[3]);
  const float J00 = cam.fx / z, J02 = -cam.fx * tx / (z * z);
  const float J11 = cam.fy / z, J12 = -cam.fy * ty / (z * z);
  for (int k = 0; k < 3; ++k) {
    T[k] = J00 * cam.R[k] + J02 * cam.R[6 + k];
    T[3 + k] = J11 * cam.R[3 + k] + J12 * cam.R[6 + k];
  }
}

// Project one Gaussian. Returns false when it is culled (camera z <= near, or the 2D
// covariance is not positive definite).
HOST_DEVICE inline bool project_gaussian(const CameraParams& cam, const float mean[3],
                                         const float Sigma[9], Projected& out) {
  mat3_vec(cam.R, mean, out.cam);
  for (int k = 0; k < 3; ++k) out.cam[k] += cam.t[k];
  const float z = out.cam[2];
  if (!(z > cam.near_plane)) return false;
  out.mean2d[0] = cam.fx * out.cam[0] / z + cam.cx;
  out.mean2d[1] = cam.fy * out.cam[1] / z + cam.cy;
  float T[6];
  projection_jacobian(cam, out.cam, T);
  // cov2d = T Sigma Tᵀ; the off-diagonal is symmetrised so that any 3x3 input works.
  float TS[6];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      TS[3 * r + k] = T[3 * r] * Sigma[k] + T[3 * r + 1] * Sigma[3 + k] + T[3 * r + 2] * Sigma[6 + k];
  const float m00 = TS[0] * T[0] + TS[1] * T[1] + TS[2] * T[2];
  const float m01 = TS[0] * T[3] + TS[1] * T[4] + TS[2] * T[5];
  const float m10 = TS[3] * T[0] + TS[4] * T[1] + TS[5] * T[2];
  const float m11 = TS[3] * T[3] + TS[4] * T[4] + TS[5] * T[5];
  const float a = m00 + kLowPass, b = 0.5f * (m01 + m10), c = m11 + kLowPass;
  const float det = a * c - b * b;
  if (!(det > 0.f) || !is_finite(det)) return false;
  out.cov2d[0] = a; out.cov2d[1] = b; out.cov2d[2] = c;
  out.det = det;
  out.conic[0] = c / det; out.conic[1] = -b / det; out.conic[2] = a / det;
  return true;
}

// radius = ceil(3 sqrt(lambda_max)) of the 2D covariance.
HOST_DEVICE inline int gaussian_radius(const float cov2d[3]) {
  const float mid = 0.5f * (cov2d[0] + cov2d[2]);
  const float disc = mid * mid - (cov2d[0] * cov2d[2] - cov2d[1] * cov2d[1]);
  const float lambda_max = mid + sqrtf(disc > 0.f ? disc : 0.f);
  return (int)ceilf(3.f * sqrtf(lambda_max));
}

// Half-extents (px) of the axis-aligned box holding every pixel centre where
// opacity·G >= 1/255, i.e. the ellipse dᵀ cov2d⁻¹ d <= 2 ln(255·opacity), with a small
// safety margin for rounding. Returns false if the Gaussian can reach no pixel.
HOST_DEVICE inline bool support_extent(const float cov2d[3], float opacity, float& ex, float& ey) {
  if (!(opacity >= kAlphaMin)) return false;
  const float k2 = 2.f * logf(opacity / kAlphaMin);
  if (!(k2 >= 0.f)) return false;
  ex = 1.001f * sqrtf(k2 * cov2d[0]) + 0.01f;
  ey = 1.001f * sqrtf(k2 * cov2d[2]) + 0.01f;
  return is_finite(ex) && is_finite(ey);
}

// Inclusive tile range [tx0, tx1] x [ty0, ty1] covered by a support box; false if empty.
HOST_DEVICE inline bool tile_range(const float mean2d[2], float ex, float ey, int tiles_x,
                                   int tiles_y, int width, int height, int rect[4]) {
  const float x0 = mean2d[0] - ex, x1 = mean2d[0] + ex;
  const float y0 = mean2d[1] - ey, y1 = mean2d[1] + ey;
  // Pixel centres are at i + 0.5 for i in [0, width).
  if (!(x1 >= 0.5f && x0 <= width - 0.5f && y1 >= 0.5f && y0 <= height - 0.5f)) return false;
  const float px0 = floorf(x0 > 0.f ? x0 : 0.f), px1 = floorf(x1 < width - 0.5f ? x1 : width - 0.5f);
  const float py0 = floorf(y0 > 0.f ? y0 : 0.f), py1 = floorf(y1 < height - 0.5f ? y1 : height - 0.5f);
  rect[0] = (int)px0 / kTileSize;
  rect[1] = (int)py0 / kTileSize;
  rect[2] = (int)px1 / kTileSize;
  rect[3] = (int)py1 / kTileSize;
  if (rect[2] >= tiles_x) rect[2] = tiles_x - 1;
  if (rect[3] >= tiles_y) rect[3] = tiles_y - 1;
  return rect[0] <= rect[2] && rect[1] <= rect[3];
}

// Backward of the conic: (dA, dB, dC) on conic -> (da, db, dc) on cov2d.
HOST_DEVICE inline void conic_backward(const float cov2d[3], const float dconic[3], float dcov[3]) {
  const float a = cov2d[0], b = cov2d[1], c = cov2d[2];
  const float det = a * c - b * b;
  const float inv2 = 1.f / (det * det);
  const float gA = dconic[0], gB = dconic[1], gC = dconic[2];
  dcov[0] = inv2 * (-c * c * gA + b * c * gB - b * b * gC);
  dcov[1] = inv2 * (2.f * b * c * gA - (a * c + b * b) * gB + 2.f * a * b * gC);
  dcov[2] = inv2 * (-b * b * gA + a * b * gB - a * a * gC);
}

// Backward of project_gaussian: gradients on mean2d (2), cov2d (a, b, c) and the camera
// depth z -> gradients on the world mean (accumulated into dmean) and Sigma (written).
HOST_DEVICE inline void project_gaussian_backward(const CameraParams& cam, const float mean[3],
                                                  const float Sigma[9], const float dmean2d[2],
                                                  const float dcov2d[3], float ddepth,
                                                  float dmean[3], float dSigma[9]) {
  float p[3];
  mat3_vec(cam.R, mean, p);
  for (int k = 0; k < 3; ++k) p[k] += cam.t[k];
  const float x = p[0], y = p[1], z = p[2];
  float lim[4];
  jacobian_limits(cam, lim);
  const float rx = clamp_ratio(x / z, lim[0], lim[1]);
  const float ry = clamp_ratio(y / z, lim[2], lim[3]);
  const bool pass_x = (x / z >= lim[0]) && (x / z <= lim[1]);
  const bool pass_y = (y / z >= lim[2]) && (y / z <= lim[3]);
  const float tx = z * rx, ty = z * ry;
  const float J00 = cam.fx / z, J02 = -cam.fx * tx / (z * z);
  const float J11 = cam.fy / z, J12 = -cam.fy * ty / (z * z);
  float T[6];
  for (int k = 0; k < 3; ++k) {
    T[k] = J00 * cam.R[k] + J02 * cam.R[6 + k];
    T[3 + k] = J11 * cam.R[3 + k] + J12 * cam.R[6 + k];
  }
  // L = <G2, T Sigma Tᵀ> with G2 = [[da, db/2], [db/2, dc]].
  const float G2[4] = {dcov2d[0], 0.5f * dcov2d[1], 0.5f * dcov2d[1], dcov2d[2]};
  // dSigma = Tᵀ G2 T
  float G2T[6];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k) G2T[3 * r + k] = G2[2 * r] * T[k] + G2[2 * r + 1] * T[3 + k];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) dSigma[3 * i + j] = T[i] * G2T[j] + T[3 + i] * G2T[3 + j];
  // dT = G2 T (Sigma + Sigmaᵀ)
  float Ssym[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) Ssym[3 * i + j] = Sigma[3 * i + j] + Sigma[3 * j + i];
  float dT[6];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      dT[3 * r + k] = G2T[3 * r] * Ssym[k] + G2T[3 * r + 1] * Ssym[3 + k] + G2T[3 * r + 2] * Ssym[6 + k];
  // T = J W  =>  dJ = dT Wᵀ (only the non-zero entries of J matter)
  const float dJ00 = dT[0] * cam.R[0] + dT[1] * cam.R[1] + dT[2] * cam.R[2];
  const float dJ02 = dT[0] * cam.R[6] + dT[1] * cam.R[7] + dT[2] * cam.R[8];
  const float dJ11 = dT[3] * cam.R[3] + dT[4] * cam.R[4] + dT[5] * cam.R[5];
  const float dJ12 = dT[3] * cam.R[6] + dT[4] * cam.R[7] + dT[5] * cam.R[8];
  float dx = 0.f, dy = 0.f, dz = ddepth;
  const float z2 = z * z, z3 = z2 * z;
  dz += -cam.fx / z2 * dJ00 + 2.f * cam.fx * tx / z3 * dJ02 - cam.fy / z2 * dJ11 +
        2.f * cam.fy * ty / z3 * dJ12;
  const float dtx = -cam.fx / z2 * dJ02, dty = -cam.fy / z2 * dJ12;
  // tx = z · clamp(x/z)
  if (pass_x) { dx += dtx; dz += dtx * (rx - x / z); } else { dz += dtx * rx; }
  if (pass_y) { dy += dty; dz += dty * (ry - y / z); } else { dz += dty * ry; }
  // mean2d
  dx += cam.fx / z * dmean2d[0];
  dz += -cam.fx * x / z2 * dmean2d[0];
  dy += cam.fy / z * dmean2d[1];
  dz += -cam.fy * y / z2 * dmean2d[1];
  // p = R mean + t  =>  dmean = Rᵀ dp
  const float dp[3] = {dx, dy, dz};
  for (int k = 0; k < 3; ++k) dmean[k] += cam.R[k] * dp[0] + cam.R[3 + k] * dp[1] + cam.R[6 + k] * dp[2];
}

}  // namespace raster
}  // namespace fgs
