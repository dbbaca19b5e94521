// Crack opening inside one object: damage-field-gradient partitioning of an object's
// grid field, after Homel & Herbold (IJNME 2017) as used by AnisoMPM (Wolper et al. 2020).
// Shared by the CPU and CUDA kernels; see docs/design_mpm.md "Fragments".
//
// Per substep, for every object grid g (K of them; field A of g is grid g, field B is grid K + g):
//   1. P2G also scatters m_p D_p (damage D_p = 1 where the particle's damage flag is set, else 0;
//      the solver sets it where the current alpha is at least the material's fracture threshold
//      plus contact.damage_dilation), so D_i = sum w m D / sum w m is the mass-weighted damage at
//      node i (in [0, 1]).
//   2. Every particle gathers its damage gradient grad D_p = sum_i D_i grad w_ip (a particle whose
//      material gave it a split direction takes that, scaled, instead: apply_split_direction), and
//      every node keeps,
//      among the particles whose stencil reaches it, the one with the largest |grad D_p| (its
//      "reference"; ties broken by the particle index, so the choice is order-free: a max).
//   3. A node is split where |grad D_ref| >= split_gradient (a crack passes by). There, particle p
//      belongs to field B if grad D_p . grad D_ref < 0 (p lies on the other side of the damage
//      band than the reference particle), else to field A. Field B is summed from its particles
//      (mass, momentum, mass gradient, position moment), and field A, which holds P2G's sum of
//      all of them, becomes that sum minus B (split_node_fields).
//   4. The two fields meet through the contact decision and impulse of the collision pass
//      (contact_pair, csrc/common/mpm_math.h): momentum-conserving, frictional, separation allowed.
//   5. G2P reads, at each split node, the field its side of that node names.
#pragma once
#include <cstdint>
#include <cstring>

#include "common/hd.h"
#include "common/mpm_transfer.h"

namespace fgs {

// Damage of a particle from its damage flag (set by the solver where NACC's cohesion is gone and
// the material has opened: fracture_gs.mpm.solver.CollisionMPM.damaged). The grid transfer of
// step 1 smooths it over the B-spline support.
HOST_DEVICE inline float particle_damage(uint8_t damaged) { return damaged ? 1.f : 0.f; }

// Fragment settings and fields, as the kernels see them.
struct FragmentView {
  int n_fields;                    // K: object grids; field B of grid g is grid K + g
  uint32_t split_bits;             // float bits of split_gradient^2: nodes whose reference key has
                                   // high word >= split_bits are split
  const float* damage_gradient;    // (N, 3) grad D_p
  const int64_t* reference;        // (K * nodes) reference key per node, 0 = none
  const uint8_t* split_particle;   // (N) 1 if the particle's stencil reaches a split node
  const int32_t* side_mask;        // (N) bit 9a+3b+c set where the particle is on side B at its stencil
                                   // node (a, b, c), as the partition found; nullptr: from the references
};

// Bit of stencil node (a, b, c) in a side mask.
HOST_DEVICE inline uint32_t side_bit(int a, int b, int c) { return 1u << (9 * a + 3 * b + c); }

// Split directions: a particle's material may give it a unit vector (the brittle model: the normal
// of its crack plane once its damage is complete, fracture_gs/materials/brittle.py). Its reference
// vector is then that direction times `scale` (1/length, large enough that it splits every node its
// stencil reaches and outranks the damage gradients there) instead of its damage gradient. At a node
// whose reference is such a particle r, particle q is on side B where grad D_q . n_r < 0: the damage
// gradient of q points toward the crack, so the test separates the two half-spaces of r's crack
// plane from the first cracked particle on (a damage band needs many before its gradient reaches
// split_gradient). Rows are 0 for particles without a direction.
struct DirectionView {
  const float* direction;  // particle q's direction at direction + stride * q (3 floats), or nullptr: none
  long long stride;        // floats from one particle's row to the next
  float scale;
};

HOST_DEVICE inline void apply_split_direction(const DirectionView& directions, long long q, float gq[3]) {
  if (directions.direction == nullptr) return;
  const float* n = directions.direction + directions.stride * q;
  if (n[0] == 0.f && n[1] == 0.f && n[2] == 0.f) return;
  for (int d = 0; d < 3; ++d) gq[d] = directions.scale * n[d];
}

// Reference key of a particle with damage gradient g: the high word orders by |g|^2 (the bits of a
// non-negative float order like its value), the low word breaks ties by the particle index.
HOST_DEVICE inline int64_t damage_key(const float g[3], long long q) {
  const float norm_sq = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
  uint32_t bits;
  memcpy(&bits, &norm_sq, sizeof(bits));
  return (int64_t)(((uint64_t)bits << 32) | (uint64_t)(uint32_t)q);
}

HOST_DEVICE inline bool key_is_split(int64_t key, uint32_t split_bits) {
  return key > 0 && (uint32_t)((uint64_t)key >> 32) >= split_bits;
}

HOST_DEVICE inline long long key_particle(int64_t key) { return (long long)(uint32_t)((uint64_t)key & 0xffffffffu); }

// True if damage gradients gq and gr point to opposite sides (gq . gr < 0).
HOST_DEVICE inline bool sides_differ(const float gq[3], const float gr[3]) {
  return (gq[0] * gr[0] + gq[1] * gr[1] + gq[2] * gr[2]) < 0.f;
}

// Field offset (0: A, 1: B) of particle q at a split node with reference particle r.
HOST_DEVICE inline int fragment_side(const float* damage_gradient, long long q, long long r) {
  return sides_differ(damage_gradient + 3 * q, damage_gradient + 3 * r) ? 1 : 0;
}

// Grid (0 .. 2K-1) that particle q of grid g uses at node `node` (index within one grid).
HOST_DEVICE inline int fragment_field(const FragmentView& f, int g, long long q, long long node, long long nodes) {
  const int64_t key = f.reference[(long long)g * nodes + node];
  if (!key_is_split(key, f.split_bits)) return g;
  return g + f.n_fields * fragment_side(f.damage_gradient, q, key_particle(key));
}

// Damage gradient of the particle at x on grid g: sum_i D_i grad w_ip, D_i = damage_i / mass_i
// (0 without mass), summed along z first, per (x, y) column.
HOST_DEVICE inline void particle_damage_gradient(const float* x, int g, const MPMGeometry& geo, const float* grid_mass,
                                                 const float* grid_damage, float mass_eps, float out[3]) {
  const GridShape& s = geo.shape;
  AxisWeights aw[3];
  stencil_weights(x, geo, aw);
  const long long grid_offset = (long long)g * s.nodes();
  out[0] = out[1] = out[2] = 0.f;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      float d[3];
      for (int c = 0; c < 3; ++c) {
        const long long idx = grid_offset + node_index(aw[0].base + a, aw[1].base + b, aw[2].base + c, s);
        const float m = grid_mass[idx];
        d[c] = m > mass_eps ? grid_damage[idx] / m : 0.f;
      }
      const float dw_sum = d[0] * aw[2].dw[0] + d[1] * aw[2].dw[1] + d[2] * aw[2].dw[2];
      const float w_sum = d[0] * aw[2].w[0] + d[1] * aw[2].w[1] + d[2] * aw[2].w[2];
      out[0] += aw[0].dw[a] * aw[1].w[b] * w_sum;
      out[1] += aw[0].w[a] * aw[1].dw[b] * w_sum;
      out[2] += aw[0].w[a] * aw[1].w[b] * dw_sum;
    }
}

// One particle's P2G contribution to stencil node (a, b, c): mass, momentum (APIC: m v + A (x_i -
// x_p)), mass gradient m grad w and position moment w m (x_p - x_i), added to the given node fields.
HOST_DEVICE inline void p2g_node_add(const AxisWeights aw[3], int a, int b, int c, float m, const float* mv,
                                     const float A[9], float dx, float* mass, float* momentum, float* mass_gradient,
                                     float* moment) {
  const float w = aw[0].w[a] * aw[1].w[b] * aw[2].w[c];
  const float px = ((float)a - aw[0].f) * dx, py = ((float)b - aw[1].f) * dx, pz = ((float)c - aw[2].f) * dx;
  *mass += w * m;
  for (int d = 0; d < 3; ++d) momentum[d] += w * (mv[d] + A[3 * d] * px + A[3 * d + 1] * py + A[3 * d + 2] * pz);
  mass_gradient[0] += m * aw[0].dw[a] * aw[1].w[b] * aw[2].w[c];
  mass_gradient[1] += m * aw[0].w[a] * aw[1].dw[b] * aw[2].w[c];
  mass_gradient[2] += m * aw[0].w[a] * aw[1].w[b] * aw[2].dw[c];
  moment[0] -= w * m * px;
  moment[1] -= w * m * py;
  moment[2] -= w * m * pz;
}

// Share of a split node's P2G mass below which its side A counts as empty once side B's share is
// taken out: P2G's sum minus B is then rounding noise (every particle there is on side B).
constexpr float kEmptySideShare = 1e-5f;

// Fields A (index ia) and B (ib) of a split node: A holds P2G's sum over all the node's particles,
// B the share of the particles on side B. A becomes the side-A share, P2G's sum minus B (mass,
// momentum, mass gradient, position moment). Where that leaves only rounding noise, B takes the
// whole sum and A is emptied exactly. Either way A + B is P2G's sum, so momentum is kept.
HOST_DEVICE inline void split_node_fields(long long ia, long long ib, float* mass, float* momentum,
                                          float* mass_gradient, float* moment) {
  const float total = mass[ia];
  const float side_a = total - mass[ib];
  float* vectors[3] = {momentum, mass_gradient, moment};
  if (side_a <= kEmptySideShare * total) {
    mass[ib] = total;
    mass[ia] = 0.f;
    for (float* field : vectors)
      for (int d = 0; d < 3; ++d) {
        field[3 * ib + d] = field[3 * ia + d];
        field[3 * ia + d] = 0.f;
      }
    return;
  }
  mass[ia] = side_a;
  for (float* field : vectors)
    for (int d = 0; d < 3; ++d) field[3 * ia + d] -= field[3 * ib + d];
}

// Node velocities of particle q of grid g with fragments: at a split node the field of q's side.
struct FragmentNodeVelocity {
  const float* grid_velocity;  // all 2K grids
  const FragmentView* frag;
  int g;
  long long q;
  long long nodes;
  HOST_DEVICE const float* operator()(long long node) const {
    return grid_velocity + 3 * ((long long)fragment_field(*frag, g, q, node, nodes) * nodes + node);
  }
};

// G2P gather of particle q when its stencil reaches a split node: as g2p_gather, but each node's
// velocity comes from the field (A or B) the particle belongs to there.
HOST_DEVICE inline bool g2p_gather_fragments(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                                             const float* grid_velocity, const FragmentView& f,
                                             const G2POutputs& out, float F_trial[9]) {
  const FragmentNodeVelocity velocity{grid_velocity, &f, in.grid_id[q], q, geo.shape.nodes()};
  return g2p_gather_nodes(q, in, geo, dt, velocity, out, F_trial);
}

// G2P of particle q with fragments (frag may be nullptr: none): the split-aware gather for
// particles whose stencil reaches a split node, then the material update as g2p_particle.
HOST_DEVICE inline bool g2p_particle_fragments(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                                               const float* grid_velocity, const FragmentView* frag,
                                               const G2POutputs& out) {
  if (frag == nullptr || !frag->split_particle[q]) return g2p_particle(q, in, geo, dt, grid_velocity, out);
  float F[9];
  const bool clamped = g2p_gather_fragments(q, in, geo, dt, grid_velocity, *frag, out, F);
  g2p_material(q, in, out, F);
  return clamped;
}

}  // namespace fgs
