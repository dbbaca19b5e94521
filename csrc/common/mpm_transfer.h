// Per-particle and per-node MPM transfer steps shared by the CPU and CUDA kernels: the loops in
// csrc/mpm/mpm_cpu.cpp and csrc/mpm/mpm_cuda.cu call these functions and differ only in how they
// iterate.
#pragma once
#include <cstdint>

#include "common/constitutive.h"
#include "common/hd.h"
#include "common/mat3.h"
#include "common/mpm_math.h"

namespace fgs {

// Geometry shared by all MPM kernels.
struct MPMGeometry {
  float lower[3];   // domain lower corner
  float dx;
  float inv_dx;
  GridShape shape;  // blocks per axis (same for every object grid)
  int n_grids;      // objects in collision mode, 1 in mls mode
};

// Stencil weights of a particle at x (3 floats) along the three axes.
HOST_DEVICE inline void stencil_weights(const float* x, const MPMGeometry& geo, AxisWeights aw[3]) {
  for (int d = 0; d < 3; ++d) aw[d] = axis_weights(grid_coordinate(x[d], geo.lower[d], geo.inv_dx), geo.inv_dx);
}

// The first stencil node alone (aw[d].base of stencil_weights, from the same grid coordinate).
HOST_DEVICE inline void stencil_base(const float* x, const MPMGeometry& geo, int base[3]) {
  for (int d = 0; d < 3; ++d) base[d] = axis_base(grid_coordinate(x[d], geo.lower[d], geo.inv_dx));
}

struct G2PInputs {
  const float* x;
  const float* F_E;
  const float* state;           // (N, state_stride) material state (csrc/common/material_law.h)
  int state_stride;
  const uint8_t* fractured;
  const int32_t* grid_id;
  const int32_t* material_id;
  const float* material_table;  // (M, kMatFields)
  float clamp_lower[3];         // particle positions are clamped into [clamp_lower, clamp_upper]
  float clamp_upper[3];
};

struct G2POutputs {
  float* x;
  float* v;
  float* C;
  float* F_E;
  float* state;   // (N, state_stride) like the input
  float* stress;
  uint8_t* fractured;
  float* dissipated = nullptr;  // (N) energy per unit rest volume the update took in the substep, or nullptr
};

// Health of the particles after G2P, reduced over all particles (order-independent).
struct G2PStats {
  long long clamped;          // positions clamped into the domain
  long long first_nonfinite;  // smallest index with a non-finite x, v or F_E; -1 if none
  float max_speed;            // largest |v|
};

// True if particle q's new position, velocity and deformation gradient are all finite.
HOST_DEVICE inline bool particle_is_finite(long long q, const G2POutputs& out) {
  float sum = 0.f;  // NaN or Inf anywhere makes the sum non-finite
  for (int d = 0; d < 3; ++d) sum += out.x[3 * q + d] * 0.f + out.v[3 * q + d] * 0.f;
  for (int i = 0; i < 9; ++i) sum += out.F_E[9 * q + i] * 0.f;
  return sum == 0.f;
}

// Squared speed of particle q after G2P.
HOST_DEVICE inline float particle_speed_sq(long long q, const G2POutputs& out) {
  const float* v = out.v + 3 * q;
  return v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
}

// Grid update of one node: velocity = (momentum + mass dt g) / mass, or zero without mass. Gravity is
// added to the momentum: every node of a body in free flight has the same velocity, so a dt g added
// to the velocity would round the same way on every node, and the body would gain or lose a few
// 1e-3 of gravity's impulse each substep (the momentum's rounding differs from node to node).
HOST_DEVICE inline void grid_node_velocity(float mass, const float* momentum, float dt, const float* gravity,
                                           float mass_eps, float* velocity) {
  for (int d = 0; d < 3; ++d) velocity[d] = mass > mass_eps ? (momentum[d] + mass * (dt * gravity[d])) / mass : 0.f;
}

// The end of a G2P gather, given the particle's new velocity vp and APIC matrix C: advects and
// clamps the position, writes x, v, C of `out` and returns F_trial = (I + dt C) F_E. Returns
// true if the position had to be clamped into the domain.
HOST_DEVICE inline bool g2p_advect(long long q, const G2PInputs& in, float dt, const float vp[3], const float C[9],
                                   const G2POutputs& out, float F_trial[9]) {
  bool clamped = false;
  for (int d = 0; d < 3; ++d) {
    float xn = in.x[3 * q + d] + dt * vp[d];
    if (xn < in.clamp_lower[d]) { xn = in.clamp_lower[d]; clamped = true; }
    if (xn > in.clamp_upper[d]) { xn = in.clamp_upper[d]; clamped = true; }
    out.x[3 * q + d] = xn;
    out.v[3 * q + d] = vp[d];
  }
  for (int i = 0; i < 9; ++i) out.C[9 * q + i] = C[i];
  float G[9];
  for (int i = 0; i < 9; ++i) G[i] = dt * C[i] + ((i % 4 == 0) ? 1.f : 0.f);
  mat3_mul(G, in.F_E + 9 * q, F_trial);
  return clamped;
}

// G2P gather of particle q with the velocity of each stencil node given by node_velocity(node)
// (node: index within one grid; returns a pointer to 3 floats): v and the APIC matrix C, the
// advected (and clamped) position, and F_trial = (I + dt C) F_E for the return map. Writes x, v, C
// of `out`; returns true if the position had to be clamped into the domain.
template <class NodeVelocity>
HOST_DEVICE inline bool g2p_gather_nodes(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                                         const NodeVelocity& node_velocity, const G2POutputs& out,
                                         float F_trial[9]) {
  const GridShape& s = geo.shape;
  const float dx = geo.dx;
  AxisWeights aw[3];
  stencil_weights(in.x + 3 * q, geo, aw);
  float vp[3] = {0.f, 0.f, 0.f};
  float B[9] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
  for (int a = 0; a < 3; ++a) {
    const int ox = offset_x(aw[0].base + a, s);
    const float px = ((float)a - aw[0].f) * dx;
    for (int b = 0; b < 3; ++b) {
      const int oy = offset_y(aw[1].base + b, s);
      const float py = ((float)b - aw[1].f) * dx;
      const float wab = aw[0].w[a] * aw[1].w[b];
      for (int c = 0; c < 3; ++c) {
        const float w = wab * aw[2].w[c];
        const float pz = ((float)c - aw[2].f) * dx;
        const float* vi = node_velocity((long long)(ox + oy + offset_z(aw[2].base + c, s)));
        for (int d = 0; d < 3; ++d) {
          const float wv = w * vi[d];
          vp[d] += wv;
          B[3 * d] += wv * px;
          B[3 * d + 1] += wv * py;
          B[3 * d + 2] += wv * pz;
        }
      }
    }
  }
  const float apic_scale = 4.f * geo.inv_dx * geo.inv_dx;
  float C[9];
  for (int i = 0; i < 9; ++i) C[i] = apic_scale * B[i];
  return g2p_advect(q, in, dt, vp, C, out, F_trial);
}

// Node velocities of one grid (3 floats per node).
struct GridNodeVelocity {
  const float* velocity;
  HOST_DEVICE const float* operator()(long long node) const { return velocity + 3 * node; }
};

// G2P gather of particle q from its own grid (g2p_gather_nodes).
HOST_DEVICE inline bool g2p_gather(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                                   const float* grid_velocity, const G2POutputs& out, float F_trial[9]) {
  const GridNodeVelocity velocity{grid_velocity + 3 * (long long)in.grid_id[q] * geo.shape.nodes()};
  return g2p_gather_nodes(q, in, geo, dt, velocity, out, F_trial);
}

// Material row of particle q.
HOST_DEVICE inline const float* g2p_material_row(long long q, const G2PInputs& in) {
  return in.material_table + (long long)in.material_id[q] * kMatFields;
}

// Stores the result of particle q's update (state: kMaxStateFields floats; dissipated: the energy
// it took) and latches its fracture flag (state field 0 at the material's threshold).
HOST_DEVICE inline void g2p_store_material(long long q, const G2PInputs& in, const G2POutputs& out, const float F_E[9],
                                           const float* state, const float tau[9], float dissipated) {
  if (out.dissipated != nullptr) out.dissipated[q] = dissipated;
  for (int i = 0; i < 9; ++i) {
    out.F_E[9 * q + i] = F_E[i];
    out.stress[9 * q + i] = tau[i];
  }
  store_state(state, in.state_stride, q, out.state);
  out.fractured[q] = (in.fractured[q] || state[0] >= g2p_material_row(q, in)[kMatFractureThreshold]) ? 1 : 0;
}

// The material part of G2P: update of F_trial (overwritten), stress, state, fracture flag.
HOST_DEVICE inline void g2p_material(long long q, const G2PInputs& in, const G2POutputs& out, float F[9]) {
  float state[kMaxStateFields], tau[9], dissipated;
  load_state(in.state, in.state_stride, q, state);
  constitutive_update(g2p_material_row(q, in), F, state, tau, &dissipated);
  g2p_store_material(q, in, out, F, state, tau, dissipated);
}

// G2P of particle q: gather and advection (g2p_gather), the material's update on F_trial, and
// the fracture flag. Returns true if the position had to be clamped.
HOST_DEVICE inline bool g2p_particle(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                                     const float* grid_velocity, const G2POutputs& out) {
  float F[9];
  const bool clamped = g2p_gather(q, in, geo, dt, grid_velocity, out, F);
  g2p_material(q, in, out, F);
  return clamped;
}

}  // namespace fgs
