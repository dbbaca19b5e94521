// Per-pixel math of the rasterizer (SPEC §6.1), shared by the CPU and CUDA kernels: the
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
