// FPGO geometry shared by the CPU and CUDA kernels (docs/formulas.md §13, paper App. A.4).
//
// lens_ellipsoid: the ellipsoid that stands in for the overlap ("lens") of two spheres
// (C_i, r_i), (C_j, r_j), d = |C_j - C_i|, u = (C_j - C_i) / d:
//   intersecting, |r_i - r_j| < d < r_i + r_j:
//     centre  c = C_i + r_i / (r_i + r_j) (C_j - C_i)
//     semi-axis along u          a = (r_i + r_j - d) / 2        (half the lens thickness)
//     two semi-axes across u     b = sqrt(r_i^2 - ((d^2 + r_i^2 - r_j^2) / (2d))^2)
//                                  (radius of the circle where the spheres meet)
//     rotation R = [u v w], v ⟂ u, w = u × v
//   contained, d <= |r_i - r_j|: the overlap is the smaller sphere, which is its own minimal
//     enclosing ellipsoid: centre and radius of that sphere, R = I (any rotation fits).
//   tangent or disjoint, d >= r_i + r_j: no overlap, valid = false.
// Gaussian scales are the semi-axes / k_sigma (a sphere of radius r stands for a Gaussian of
// scale r / k_sigma); covariance R diag(s^2) R^T = s_b^2 I + (s_a^2 - s_b^2) u u^T.
// Every branch is free of divisions by d when d -> 0 (that case is "contained").
#pragma once
#include <cmath>

#include "common/hd.h"

namespace fgs {
namespace mvee {

struct Lens {
  float centre[3];
  float scales[3];    // Gaussian scales along R's columns (semi-axes / k_sigma)
  float rotation[9];  // row-major; columns are the axes u, v, w
  float covariance[9];
  bool valid;
};

// A unit vector orthogonal to the unit vector u (cross product with the least aligned axis).
HOST_DEVICE inline void orthogonal_unit(const float u[3], float v[3]) {
  const float ax = fabsf(u[0]), ay = fabsf(u[1]), az = fabsf(u[2]);
  float e[3] = {0.f, 0.f, 0.f};
  if (ax <= ay && ax <= az) e[0] = 1.f;
  else if (ay <= az) e[1] = 1.f;
  else e[2] = 1.f;
  v[0] = u[1] * e[2] - u[2] * e[1];
  v[1] = u[2] * e[0] - u[0] * e[2];
  v[2] = u[0] * e[1] - u[1] * e[0];
  const float inv = 1.f / sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  v[0] *= inv; v[1] *= inv; v[2] *= inv;
}

HOST_DEVICE inline void axisymmetric_covariance(const float u[3], float s_axis, float s_across,
                                                float cov[9]) {
  const float across2 = s_across * s_across, extra = s_axis * s_axis - across2;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) cov[3 * r + c] = (r == c ? across2 : 0.f) + extra * u[r] * u[c];
}

HOST_DEVICE inline Lens lens_ellipsoid(const float ci[3], float ri, const float cj[3], float rj,
                                       float k_sigma) {
  Lens out;
  const float delta[3] = {cj[0] - ci[0], cj[1] - ci[1], cj[2] - ci[2]};
  const float d = sqrtf(delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]);
  const float inv_k = 1.f / k_sigma;
  if (!(ri > 0.f) || !(rj > 0.f) || !(d < ri + rj)) {  // tangent, disjoint, or bad input
    for (int a = 0; a < 3; ++a) { out.centre[a] = ci[a]; out.scales[a] = 0.f; }
    for (int a = 0; a < 9; ++a) { out.rotation[a] = (a % 4 == 0) ? 1.f : 0.f; out.covariance[a] = 0.f; }
    out.valid = false;
    return out;
  }
  out.valid = true;
  if (d <= fabsf(ri - rj)) {  // one sphere inside the other: the smaller one is the overlap
    const bool i_smaller = ri <= rj;
    const float r = i_smaller ? ri : rj;
    const float* c = i_smaller ? ci : cj;
    const float s = r * inv_k;
    for (int a = 0; a < 3; ++a) { out.centre[a] = c[a]; out.scales[a] = s; }
    for (int a = 0; a < 9; ++a) {
      out.rotation[a] = (a % 4 == 0) ? 1.f : 0.f;
      out.covariance[a] = (a % 4 == 0) ? s * s : 0.f;
    }
    return out;
  }
  // Intersecting: d > |ri - rj| >= 0, so d > 0.
  const float u[3] = {delta[0] / d, delta[1] / d, delta[2] / d};
  const float t = ri / (ri + rj);
  for (int a = 0; a < 3; ++a) out.centre[a] = ci[a] + t * delta[a];
  const float semi_axis = 0.5f * (ri + rj - d);
  // distance from C_i to the plane of the intersection circle; (ri-rj)(ri+rj) keeps it exact
  // when the radii are equal
  const float h = 0.5f * d + (ri - rj) * (ri + rj) / (2.f * d);
  const float semi_across = sqrtf(fmaxf(ri * ri - h * h, 0.f));
  float v[3], w[3];
  orthogonal_unit(u, v);
  w[0] = u[1] * v[2] - u[2] * v[1];
  w[1] = u[2] * v[0] - u[0] * v[2];
  w[2] = u[0] * v[1] - u[1] * v[0];
  for (int r = 0; r < 3; ++r) {
    out.rotation[3 * r + 0] = u[r];
    out.rotation[3 * r + 1] = v[r];
    out.rotation[3 * r + 2] = w[r];
  }
  out.scales[0] = semi_axis * inv_k;
  out.scales[1] = out.scales[2] = semi_across * inv_k;
  axisymmetric_covariance(u, out.scales[0], out.scales[1], out.covariance);
  return out;
}

}  // namespace mvee
}  // namespace fgs
