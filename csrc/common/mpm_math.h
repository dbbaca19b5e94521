// MLS-MPM math shared by the CPU and CUDA kernels (docs/formulas.md §2, §7, §9).
//
// Grid layout: nodes are stored block-major. A block is 4x4x4 nodes (64 consecutive floats);
// blocks are ordered x-major: block = (bi * by + bj) * bz + bk. The linear node index is
// separable, index(i,j,k) = axis_offset_x(i) + axis_offset_y(j) + axis_offset_z(k), which lets
// the 27-node stencil be addressed with three small per-axis tables.
#pragma once
#include <cmath>

#include "common/hd.h"

namespace fgs {

constexpr int kBlockBits = 2;
constexpr int kBlock = 1 << kBlockBits;      // nodes per block edge
constexpr int kBlockNodes = kBlock * kBlock * kBlock;

struct GridShape {
  int bx, by, bz;  // blocks per axis
  HOST_DEVICE int blocks() const { return bx * by * bz; }
  HOST_DEVICE long long nodes() const { return (long long)blocks() * kBlockNodes; }
};

HOST_DEVICE inline int offset_x(int i, const GridShape& s) {
  return (i >> kBlockBits) * s.by * s.bz * kBlockNodes + (i & (kBlock - 1)) * kBlock * kBlock;
}
HOST_DEVICE inline int offset_y(int j, const GridShape& s) {
  return (j >> kBlockBits) * s.bz * kBlockNodes + (j & (kBlock - 1)) * kBlock;
}
HOST_DEVICE inline int offset_z(int k, const GridShape& s) {
  return (k >> kBlockBits) * kBlockNodes + (k & (kBlock - 1));
}
HOST_DEVICE inline int node_index(int i, int j, int k, const GridShape& s) {
  return offset_x(i, s) + offset_y(j, s) + offset_z(k, s);
}
// Block coordinates (x, y, z, in blocks) of a block id (blocks x-major, as node_index stores them).
HOST_DEVICE inline void block_coords(int block, const GridShape& s, int* ijk) {
  ijk[0] = block / (s.by * s.bz);
  ijk[1] = (block / s.bz) % s.by;
  ijk[2] = block % s.bz;
}
// Inverse of node_index: integer node coordinates of a linear index.
HOST_DEVICE inline void node_coords(int index, const GridShape& s, int* ijk) {
  const int local = index % kBlockNodes;
  block_coords(index / kBlockNodes, s, ijk);
  ijk[0] = ijk[0] * kBlock + local / (kBlock * kBlock);
  ijk[1] = ijk[1] * kBlock + (local / kBlock) % kBlock;
  ijk[2] = ijk[2] * kBlock + local % kBlock;
}

// Quadratic B-spline weights of one particle along one axis.
// X is the particle coordinate in cell units; base = floor(X - 0.5), f = X - base in [0.5, 1.5).
// w[a] is the weight of node base + a, dw[a] its derivative with respect to the particle
// position (in 1/length units: divide by dx).
struct AxisWeights {
  int base;
  float f;
  float w[3];
  float dw[3];
};

// a * b rounded to float, out of reach of FMA contraction (-ffp-contract=fast, nvcc's default
// fmad): __fmul_rn on the device, an empty asm on the host, which costs no instruction. Left to
// itself the compiler fuses a product with the add that follows it in some places and not in
// others, so one formula inlined into two kernels rounds two ways.
HOST_DEVICE inline float product_rn(float a, float b) {
#if defined(__CUDA_ARCH__)
  return __fmul_rn(a, b);
#elif defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
  float p = a * b;
  asm("" : "+x"(p));
  return p;
#elif defined(__GNUC__) && defined(__aarch64__)
  float p = a * b;
  asm("" : "+w"(p));
  return p;
#else
  volatile float p = a * b;
  return p;
#endif
}

// Grid coordinate X = (x - lower) * inv_dx of a position along one axis, rounded to float
// before anything else uses it. Every kernel, and the torch twin, must find the same stencil base
// floor(X - 0.5) for a particle: the binning sorts particles by it and P2G writes into the window
// of the block it names; a product fused with the - 0.5 (or with f = X - base) in one kernel and
// not in another would give a particle within a rounding of a block boundary two different bases.
HOST_DEVICE inline float grid_coordinate(float x, float lower, float inv_dx) { return product_rn(x - lower, inv_dx); }

// First stencil node along one axis of a particle at grid coordinate X (grid_coordinate; X - 0.5
// is exact below 2^23).
HOST_DEVICE inline int axis_base(float X) { return (int)floorf(X - 0.5f); }

HOST_DEVICE inline AxisWeights axis_weights(float X, float inv_dx) {
  AxisWeights a;
  a.base = axis_base(X);
  a.f = X - (float)a.base;
  float f = a.f;
  // The squares are rounded before the 0.75 - ...: P2G and G2P must weigh a particle exactly alike
  // (a moving body's momentum drifts by a few 1e-8 of itself per substep where they do not).
  a.w[0] = 0.5f * product_rn(1.5f - f, 1.5f - f);
  a.w[1] = 0.75f - product_rn(f - 1.f, f - 1.f);
  a.w[2] = 0.5f * product_rn(f - 0.5f, f - 0.5f);
  a.dw[0] = -(1.5f - f) * inv_dx;
  a.dw[1] = -2.f * (f - 1.f) * inv_dx;
  a.dw[2] = (f - 0.5f) * inv_dx;
  return a;
}

// APIC affine momentum matrix A = m C - (4 dt / dx^2) V0 tau (row-major 3x3).
HOST_DEVICE inline void apic_affine(const float* C, const float* tau, float mass, float rest_volume,
                                    float dt, float inv_dx, float* A) {
  float stress_scale = 4.f * dt * inv_dx * inv_dx * rest_volume;
  for (int i = 0; i < 9; ++i) A[i] = mass * C[i] - stress_scale * tau[i];
}

// ---------------------------------------------------------------------------------------------
// Contact between two velocity fields at one grid node (docs/formulas.md §7). Each field is a body (an
// object grid in collision mode; crack opening reuses this for the two sides of a crack inside one
// object) and brings, at the node: its mass, velocity, mass gradient g = sum m_p grad w (points
// out of the body) and position moment s = sum w m_p (x_p - x_i) (s / m: the body's mass centre
// seen from the node).
//
// Detection (docs/design_mpm.md, Contact detection): the bodies are in contact at the
// node only where their mass centres, taken along the normal, are closer than max_gap:
//     (s_b / m_b - s_a / m_a) . n < max_gap          (Lemiale et al. 2010, Nairn 2013)
// Touching thick bodies give about 0.81-0.9 dx there (a half-space's mass centre lies ~0.4 dx
// behind its surface, seen through the quadratic B-spline), touching one-layer sheets their
// particle spacing; bodies further apart give more. The rest-volume check it replaces (V_a +
// V_b >= 0.75 dx^3) never fired for thin or surface-only bodies, which then passed through each
// other.
//
// Normal: The averaged normal normalize(g_a / |g_a| - g_b / |g_b|) needs both unit gradients to be the
// bodies' surface normals, which fails for a one-layer sheet (a shard) at two kinds of nodes, and
// there the other body's unit gradient alone is the normal:
//  * nodes inside a body's mass, where its mass centre lies within `inside` (0.4 dx) of the node
//    and the other body's does not: a sheet passing through the node has almost no gradient across
//    it, and what is left points along it (toward its edge, along its density variations);
//  * nodes behind a body: its unit gradient points away from the other body's mass centre
//    (g_a . d <= 0 with d = s_b / m_b - s_a / m_a) while the other's points toward it. Seen from
//    the far side of a sheet, g_a points away from the body it meets; the average of the two unit
//    gradients then cancels, and those nodes, whose velocities the sheet's particles also gather,
//    carried no contact at all.
// Elsewhere (both bodies outside each other's mass, each gradient facing the other body, as for
// thick bodies and their corners) the normal is the averaged one, so the gap check still rejects the tilted
// normals at a sliding block's corners.
struct ContactParams {
  float impulse_scale;  // s = contact.impulse_scale, 0 <= s <= 2
  float friction;  // Coulomb coefficient mu_f between the bodies
  float mass_eps;  // nodes with mass <= mass_eps carry no field
  float max_gap;   // contact where the mass-centre gap along n is below this (length units)
  float inside;    // a body whose mass centre lies closer than this to the node gives no normal (length)
};

// One body's field at a node.
struct ContactSide {
  float mass;
  float* velocity;                // 3 floats, updated in place
  const float* mass_gradient;     // 3 floats
  const float* position_moment;   // 3 floats
};

// Unit vector along g (zero where g vanishes); returns |g|.
HOST_DEVICE inline float contact_unit(const float* g, float u[3]) {
  const float norm = sqrtf(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
  for (int d = 0; d < 3; ++d) u[d] = norm > 0.f ? g[d] / norm : 0.f;
  return norm;
}

// Offset between the two bodies' mass centres seen from the node, d = s_b / m_b - s_a / m_a.
HOST_DEVICE inline void contact_offset(const ContactSide& a, const ContactSide& b, float d[3]) {
  for (int k = 0; k < 3; ++k) d[k] = b.position_moment[k] / b.mass - a.position_moment[k] / a.mass;
}

// True if the body's mass centre seen from the node, s / m, lies closer than `inside` to it.
HOST_DEVICE inline bool contact_inside(const ContactSide& k, float inside) {
  const float* s = k.position_moment;
  const float r = inside * k.mass;
  return s[0] * s[0] + s[1] * s[1] + s[2] * s[2] < r * r;
}

// Contact normal from a toward b (see above), given the mass-centre offset d:
// n = normalize(w_a u_a - w_b u_b) with the unit gradients u and w = 1, except w = 0 for
//   1. the body whose mass centre lies within `inside` of the node, if the other's does not;
//   2. otherwise the body whose unit gradient does not point toward the other's mass centre
//      (u_a . d <= 0 for a, u_b . d >= 0 for b), if the other's does.
// False where a gradient that is used vanishes, or the two cancel (no direction).
HOST_DEVICE inline bool contact_normal(const ContactSide& a, const ContactSide& b, const float d[3], float inside,
                                       float n[3]) {
  float ua[3], ub[3];
  const float na = contact_unit(a.mass_gradient, ua), nb = contact_unit(b.mass_gradient, ub);
  const bool a_inside = contact_inside(a, inside), b_inside = contact_inside(b, inside);
  const bool a_faces_b = ua[0] * d[0] + ua[1] * d[1] + ua[2] * d[2] > 0.f;
  const bool b_faces_a = ub[0] * d[0] + ub[1] * d[1] + ub[2] * d[2] < 0.f;
  float wa = 1.f, wb = 1.f;
  if (a_inside != b_inside) {
    (a_inside ? wa : wb) = 0.f;
  } else if (a_faces_b != b_faces_a) {
    (a_faces_b ? wb : wa) = 0.f;
  }
  if ((wa > 0.f && !(na > 0.f)) || (wb > 0.f && !(nb > 0.f))) return false;
  for (int k = 0; k < 3; ++k) n[k] = wa * ua[k] - wb * ub[k];
  const float nn = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(nn > 1e-6f)) return false;
  for (int k = 0; k < 3; ++k) n[k] /= nn;
  return true;
}

// The impulse of docs/formulas.md §7 (Bardenhagen's centre-of-mass form) along the unit normal n: applied
// only while the fields approach, dp_a = -s j_n n - friction, dp_b = -dp_a (momentum is conserved
// at the node). Friction: j_t = min(mu_f s j_n, m_r |v_t|) against the tangential relative
// velocity. Returns true if an impulse was applied.
HOST_DEVICE inline bool contact_impulse(float ma, float mb, float* va, float* vb, const float n[3], float impulse_scale,
                                        float friction) {
  const float vrel[3] = {va[0] - vb[0], va[1] - vb[1], va[2] - vb[2]};
  const float vn = vrel[0] * n[0] + vrel[1] * n[1] + vrel[2] * n[2];
  if (!(vn > 0.f)) return false;  // separating or resting: no impulse
  const float reduced = ma * mb / (ma + mb);
  const float jn = reduced * vn;
  float dp[3];
  for (int d = 0; d < 3; ++d) dp[d] = -impulse_scale * jn * n[d];
  if (friction > 0.f) {
    const float vt[3] = {vrel[0] - vn * n[0], vrel[1] - vn * n[1], vrel[2] - vn * n[2]};
    const float vt_norm = sqrtf(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
    if (vt_norm > 1e-12f) {
      const float jt = fminf(friction * impulse_scale * jn, reduced * vt_norm);
      for (int d = 0; d < 3; ++d) dp[d] -= jt * vt[d] / vt_norm;
    }
  }
  for (int d = 0; d < 3; ++d) {
    va[d] += dp[d] / ma;
    vb[d] -= dp[d] / mb;
  }
  return true;
}

// The contact decision and impulse between two fields at one node: both carry mass, the normal
// is defined, the mass centres are closer than max_gap along it (d . n < max_gap), and the fields
// approach.
// Returns true if an impulse was applied.
HOST_DEVICE inline bool contact_pair(const ContactSide& a, const ContactSide& b, const ContactParams& c) {
  if (!(a.mass > c.mass_eps) || !(b.mass > c.mass_eps)) return false;
  float d[3], n[3];
  contact_offset(a, b, d);
  if (!contact_normal(a, b, d, c.inside, n)) return false;
  if (!(d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < c.max_gap)) return false;
  return contact_impulse(a.mass, b.mass, a.velocity, b.velocity, n, c.impulse_scale, c.friction);
}

// Contact pass at one node for every pair of object grids, in a fixed order (a < b).
// node: index within one grid; nodes: nodes per grid; moment: position moments (3 per node).
HOST_DEVICE inline void contact_node(long long node, long long nodes, int n_grids, const float* mass,
                                     float* velocity, const float* mass_gradient, const float* moment,
                                     const ContactParams& c) {
  for (int a = 0; a < n_grids; ++a) {
    const long long ia = a * nodes + node;
    if (!(mass[ia] > c.mass_eps)) continue;
    const ContactSide side_a{mass[ia], velocity + 3 * ia, mass_gradient + 3 * ia, moment + 3 * ia};
    for (int b = a + 1; b < n_grids; ++b) {
      const long long ib = b * nodes + node;
      const ContactSide side_b{mass[ib], velocity + 3 * ib, mass_gradient + 3 * ib, moment + 3 * ib};
      contact_pair(side_a, side_b, c);
    }
  }
}

// Boundary settings shared by the kernels (docs/formulas.md §9).
enum WallCondition { kWallNone = 0, kWallSlip = 1, kWallSticky = 2, kWallSeparate = 3 };

struct BoundaryParams {
  int wall_condition;     // WallCondition for the domain box, kWallNone if no box boundary
  int wall_cells;         // wall thickness in cells (3)
  int cells[3];           // cells per axis of the domain (nodes 0..cells)
  int has_ground;         // 1 if a ground half-space z >= ground_height exists
  float ground_height;    // in world units
  float ground_friction;  // Coulomb coefficient
  float lower_z;          // domain lower corner z, world units
  float dx;
};

// Applies the domain walls and the ground to one node velocity (node coords ijk).
HOST_DEVICE inline void apply_boundary(const int* ijk, const BoundaryParams& b, float* v) {
  if (b.wall_condition != kWallNone) {
    for (int d = 0; d < 3; ++d) {
      bool lower = ijk[d] < b.wall_cells;
      bool upper = ijk[d] > b.cells[d] - b.wall_cells;
      if (!lower && !upper) continue;
      if (b.wall_condition == kWallSticky) {
        v[0] = v[1] = v[2] = 0.f;
        return;
      }
      bool into_wall = lower ? (v[d] < 0.f) : (v[d] > 0.f);
      if (b.wall_condition == kWallSlip || into_wall) v[d] = 0.f;
    }
  }
  if (b.has_ground) {
    float z = b.lower_z + ijk[2] * b.dx;
    if (z <= b.ground_height && v[2] < 0.f) {
      float vn = -v[2];  // speed into the ground
      v[2] = 0.f;
      float vt = sqrtf(v[0] * v[0] + v[1] * v[1]);
      if (vt > 0.f) {
        float scale = fmaxf(0.f, 1.f - b.ground_friction * vn / vt);
        v[0] *= scale;
        v[1] *= scale;
      }
    }
  }
}

}  // namespace fgs
