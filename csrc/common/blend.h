// Per-pixel math of the rasterizer (docs/formulas.md §11), shared by the CPU and CUDA kernels: the
// layout of a projected Gaussian, alpha of one Gaussian at one pixel centre, and the exact
// derivative of that alpha w.r.t. the Gaussian's 2D mean, conic and opacity.
#pragma once
#include <cstdint>

#include "common/fast_math.h"
#include "common/gaussian.h"
#include "common/hd.h"

namespace fgs {
namespace raster {

// Layout of one projected Gaussian (floats): pixel mean, conic, opacity, colour, camera
// depth, and the half-extents of its support box.
enum ProjField {
  kU = 0, kV, kConicA, kConicB, kConicC, kOpacity, kRed, kGreen, kBlue, kDepth, kExtentX,
  kExtentY, kProjStride
};

// Per-(Gaussian, tile) gradient slot layout (floats).
enum SlotField {
  kGradU = 0, kGradV, kGradConicA, kGradConicB, kGradConicC, kGradOpacity, kGradRed,
  kGradGreen, kGradBlue, kGradDepth, kSlotStride
};

// e^r for |r| <= ln2/2 (the reduced argument of exp_nonpositive): degree-6 Taylor polynomial.
// T: float, or a GCC vector of floats (the CPU rasterizer's lanes).
template <class T>
HOST_DEVICE FGS_FORCE_INLINE T exp_reduced_taylor(T r) {
  const float taylor[7] = {1.f, 1.f, 0.5f, 1.f / 6.f, 1.f / 24.f, 1.f / 120.f, 1.f / 720.f};
  return fast_math::polynomial(r, taylor);
}

// exp(x) for x in [-80, 0] to ~2e-7 relative error: 2^n · p(r), |r| <= ln2/2, degree-6
// Taylor polynomial. Written branch-free so that the CPU loops vectorise; the CUDA kernels
// use the same function so both backends agree bit for bit on alpha.
HOST_DEVICE inline float exp_nonpositive(float x) {
  x = x > -80.f ? x : -80.f;
  const float n = floorf(x * 1.4426950408889634f + 0.5f);
  const float r = (x - n * 0.693145751953125f) - n * 1.428606765330187e-06f;
  return exp_reduced_taylor(r) * fast_math::bits_float(((int32_t)n + 127) << 23);
}

// Alpha of a projected Gaussian g (kProjStride floats) at the pixel centre (px, py):
// min(0.99, o·G), G = exp(-½ dᵀ conic d), d = mean2d - pixel. Returns 0 where the quadratic
// form is negative (never for a positive-definite conic). G is returned for the backward.
HOST_DEVICE inline float splat_alpha(float u, float v, float A, float B, float C, float opacity,
                                     float px, float py, float& G) {
  const float dx = u - px, dy = v - py;
  const float power = -0.5f * (A * dx * dx + C * dy * dy) - B * dx * dy;
  G = power <= 0.f ? exp_nonpositive(power) : 0.f;
  const float a = opacity * G;
  return a < kAlphaMax ? a : kAlphaMax;
}

// True when g_p comes before g_m in blending order: camera depth, ties by index (the order
// of every tile list, CPU and CUDA).
HOST_DEVICE inline bool blends_before(float depth_p, int32_t p, float depth_m, int32_t m) {
  return depth_p < depth_m || (depth_p == depth_m && p < m);
}

// Group exclusive rule (raster_kernels.h ExclusiveRule): per Gaussian m of a group, for one
// camera, the member of its group that comes before it in blending order when there is exactly
// one, kNoEarlierMember when none, kSeveralEarlierMembers otherwise. next: the group ring
// (next[m] >= 0); proj: all projected Gaussians.
constexpr int32_t kNoEarlierMember = -1;
constexpr int32_t kSeveralEarlierMembers = -2;

HOST_DEVICE inline int32_t earlier_group_member(const float* proj, const int32_t* next, int32_t m) {
  const float depth_m = proj[(int64_t)kProjStride * m + kDepth];
  int32_t found = kNoEarlierMember;
  for (int32_t p = next[m]; p != m && p >= 0; p = next[p]) {
    if (!blends_before(proj[(int64_t)kProjStride * p + kDepth], p, depth_m, m)) continue;
    if (found != kNoEarlierMember) return kSeveralEarlierMembers;
    found = p;
  }
  return found;
}

// Whether a member of Gaussian m's group that comes before m has alpha >= 1/255 at the pixel
// centre (px, py); m is then skipped there. earlier: earlier_group_member of every Gaussian.
// Culled Gaussians have zero proj (alpha 0).
HOST_DEVICE inline bool earlier_group_member_blends(const float* proj, const int32_t* next,
                                                    const int32_t* earlier, int32_t m, float px,
                                                    float py) {
  const int32_t one = earlier[m];
  if (one == kNoEarlierMember) return false;
  const float depth_m = proj[(int64_t)kProjStride * m + kDepth];
  for (int32_t p = one >= 0 ? one : next[m]; p != m && p >= 0; p = next[p]) {
    const float* g = proj + (int64_t)kProjStride * p;
    if (!blends_before(g[kDepth], p, depth_m, m)) continue;
    float G;
    if (splat_alpha(g[kU], g[kV], g[kConicA], g[kConicB], g[kConicC], g[kOpacity], px, py, G) >=
        kAlphaMin)
      return true;
    if (one >= 0) return false;  // the only earlier member
  }
  return false;
}

// Given dL/dalpha at one pixel, the gradients on (u, v, A, B, C, opacity), added to acc[6].
HOST_DEVICE inline void splat_alpha_backward(float u, float v, float A, float B, float C,
                                             float opacity, float px, float py, float G,
                                             float grad_alpha, float acc[6]) {
  const float dx = u - px, dy = v - py;
  const bool unclamped = opacity * G <= kAlphaMax;  // clamp(max) passes the gradient at equality
  const float g_opacity = unclamped ? G * grad_alpha : 0.f;
  const float g_power = unclamped ? G * opacity * grad_alpha : 0.f;
  acc[0] += g_power * (-A * dx - B * dy);
  acc[1] += g_power * (-C * dy - B * dx);
  acc[2] += -0.5f * dx * dx * g_power;
  acc[3] += -dx * dy * g_power;
  acc[4] += -0.5f * dy * dy * g_power;
  acc[5] += g_opacity;
}

}  // namespace raster
}  // namespace fgs
