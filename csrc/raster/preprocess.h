// Work on one Gaussian, shared by the CPU loop (raster_cpu.cpp) and the CUDA kernels
// (forward.cu / backward.cu): projection + colour + tile rectangle, and its exact backward.
#pragma once
#include "common/blend.h"
#include "common/gaussian.h"
#include "common/hd.h"
#include "common/sh.h"
#include "raster/raster_kernels.h"

namespace fgs {
namespace raster {

HOST_DEVICE inline void gaussian_covariance(const GaussianInputs& in, int64_t i, float Sigma[9]) {
  if (in.covariances) {
    for (int k = 0; k < 9; ++k) Sigma[k] = in.covariances[9 * i + k];
  } else {
    scale_quat_to_covariance(in.scales + 3 * i, in.quats + 4 * i, Sigma);
  }
}

// Fills proj[kProjStride], rect[4], radius and tiles touched of Gaussian i. A Gaussian that is
// culled (camera z <= near, 2D covariance not positive definite), too transparent
// (opacity < 1/255) or whose support box misses the image gets radius 0 and no tiles.
HOST_DEVICE inline void preprocess_one(const CameraParams& cam, const GaussianInputs& in, int64_t i,
                                       float* proj, int32_t* rect, int32_t* radii,
                                       int32_t* tiles_touched) {
  float* g = proj + kProjStride * i;
  for (int k = 0; k < kProjStride; ++k) g[k] = 0.f;
  for (int k = 0; k < 4; ++k) rect[4 * i + k] = 0;
  radii[i] = 0;
  tiles_touched[i] = 0;
  float Sigma[9];
  gaussian_covariance(in, i, Sigma);
  Projected P;
  if (!project_gaussian(cam, in.means + 3 * i, Sigma, P)) return;
  const float opacity = in.opacities[i];
  float ex, ey;
  if (!support_extent(P.cov2d, opacity, ex, ey)) return;
  int r[4];
  const int tiles_x = tiles_along(cam.width), tiles_y = tiles_along(cam.height);
  if (!tile_range(P.mean2d, ex, ey, tiles_x, tiles_y, cam.width, cam.height, r)) return;
  float rgb[3];
  if (in.sh) {
    float unit[3], dir[3];
    sh_view_direction(in.means + 3 * i, cam.center,
                      in.view_rotations ? in.view_rotations + 9 * i : nullptr, unit, dir);
    const int K = (in.sh_degree + 1) * (in.sh_degree + 1);
    sh_to_color(in.sh_degree, in.sh + 3 * K * i, dir, rgb);
  } else {
    for (int c = 0; c < 3; ++c) rgb[c] = in.colors[3 * i + c];
  }
  g[kU] = P.mean2d[0]; g[kV] = P.mean2d[1];
  g[kConicA] = P.conic[0]; g[kConicB] = P.conic[1]; g[kConicC] = P.conic[2];
  g[kOpacity] = opacity;
  g[kRed] = rgb[0]; g[kGreen] = rgb[1]; g[kBlue] = rgb[2];
  g[kDepth] = P.cam[2];
  g[kExtentX] = ex; g[kExtentY] = ey;
  for (int k = 0; k < 4; ++k) rect[4 * i + k] = r[k];
  radii[i] = gaussian_radius(P.cov2d);
  tiles_touched[i] = (r[2] - r[0] + 1) * (r[3] - r[1] + 1);
}

// Sums the slots of Gaussian i (in slot order) and chains the gradients to its inputs.
// Every gradient output of Gaussian i is written (zeros when it touched no tile).
HOST_DEVICE inline void preprocess_backward_one(const CameraParams& cam, const GaussianInputs& in,
                                                int64_t i, const int64_t* slot_offset,
                                                const float* slot_grads, const GaussianGrads& out) {
  float acc[kSlotStride];
  for (int k = 0; k < kSlotStride; ++k) acc[k] = 0.f;
  for (int64_t s = slot_offset[i]; s < slot_offset[i + 1]; ++s)
    for (int k = 0; k < kSlotStride; ++k) acc[k] += slot_grads[kSlotStride * s + k];
  const bool touched = slot_offset[i + 1] > slot_offset[i];
  const int K = (in.sh_degree + 1) * (in.sh_degree + 1);
  float dmean[3] = {0.f, 0.f, 0.f};
  float dSigma[9] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  float dsh[48];
  float dview[9] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  for (int k = 0; k < 3 * K; ++k) dsh[k] = 0.f;
  float Sigma[9];
  gaussian_covariance(in, i, Sigma);
  if (touched) {
    Projected P;
    project_gaussian(cam, in.means + 3 * i, Sigma, P);
    const float dconic[3] = {acc[kGradConicA], acc[kGradConicB], acc[kGradConicC]};
    float dcov2d[3];
    conic_backward(P.cov2d, dconic, dcov2d);
    const float dmean2d[2] = {acc[kGradU], acc[kGradV]};
    project_gaussian_backward(cam, in.means + 3 * i, Sigma, dmean2d, dcov2d, acc[kGradDepth], dmean,
                              dSigma);
    if (in.sh) {
      const float drgb[3] = {acc[kGradRed], acc[kGradGreen], acc[kGradBlue]};
      sh_to_color_backward(in.sh_degree, in.sh + 3 * K * i, in.means + 3 * i, cam.center,
                           in.view_rotations ? in.view_rotations + 9 * i : nullptr, drgb, dsh,
                           dmean, dview);
    }
  }
  for (int k = 0; k < 3; ++k) out.means[3 * i + k] = dmean[k];
  if (out.means2d) { out.means2d[2 * i] = acc[kGradU]; out.means2d[2 * i + 1] = acc[kGradV]; }
  if (out.opacities) out.opacities[i] = acc[kGradOpacity];
  if (out.colors) {
    out.colors[3 * i] = acc[kGradRed]; out.colors[3 * i + 1] = acc[kGradGreen];
    out.colors[3 * i + 2] = acc[kGradBlue];
  }
  if (out.sh) for (int k = 0; k < 3 * K; ++k) out.sh[3 * K * i + k] = dsh[k];
  if (out.view_rotations) for (int k = 0; k < 9; ++k) out.view_rotations[9 * i + k] = dview[k];
  if (out.covariances) for (int k = 0; k < 9; ++k) out.covariances[9 * i + k] = dSigma[k];
  if (out.scales || out.quats) {
    float ds[3] = {0.f, 0.f, 0.f}, dq[4] = {0.f, 0.f, 0.f, 0.f};
    if (touched) scale_quat_to_covariance_backward(in.scales + 3 * i, in.quats + 4 * i, dSigma, ds, dq);
    if (out.scales) for (int k = 0; k < 3; ++k) out.scales[3 * i + k] = ds[k];
    if (out.quats) for (int k = 0; k < 4; ++k) out.quats[4 * i + k] = dq[k];
  }
}

}  // namespace raster
}  // namespace fgs
