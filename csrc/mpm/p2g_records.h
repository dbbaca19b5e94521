// One particle's P2G contributions as 8-wide records, shared by P2G (csrc/mpm/mpm_cpu.cpp) and
// the fragment partition (csrc/mpm/fragments_cpu.cpp). CPU only (GCC vectors, not for nvcc).
//
// A node record is [mass, momentum xyz, position moment xyz, m D]. Per unit offset x_i - x_p the
// momentum grows by A (x_i - x_p) and the position moment by -m (x_i - x_p), so the record of
// node (a, b, c) is a weighted combination of four per-particle directions; per (x, y) column
// (a, b) they fold into two records, and node c's record is w_c in_plane + w_c pz_c along.
#pragma once

#include "common/mpm_transfer.h"
#include "mpm/cpu_vector.h"

namespace fgs {

// The particle's record directions (A: its APIC affine matrix; damage: m D, or 0).
struct ParticleRecords {
  float mass;
  Record base, affine_x, affine_y, affine_z;
};

inline ParticleRecords particle_records(float m, const float* v, const float A[9], float damage) {
  ParticleRecords r;
  r.mass = m;
  r.base = Record{m, m * v[0], m * v[1], m * v[2], 0.f, 0.f, 0.f, damage};
  r.affine_x = Record{0.f, A[0], A[3], A[6], -m, 0.f, 0.f, 0.f};
  r.affine_y = Record{0.f, A[1], A[4], A[7], 0.f, -m, 0.f, 0.f};
  r.affine_z = Record{0.f, A[2], A[5], A[8], 0.f, 0.f, -m, 0.f};
  return r;
}

// Column (a, b) of the particle's stencil, folded: the record and the mass gradient of node c
// are node_record(c) and node_gradient(c).
struct ColumnRecords {
  Record in_plane, along;
  Lane4 gradient_in_plane, gradient_along;  // mass gradient: w_c (m dwx wy, m wx dwy, 0) + dw_c (0, 0, m wx wy)
  const AxisWeights* z;
  float dx;

  Record node_record(int c) const {
    const float pz = ((float)c - z->f) * dx;
    return z->w[c] * in_plane + (z->w[c] * pz) * along;
  }
  Lane4 node_gradient(int c) const { return z->w[c] * gradient_in_plane + z->dw[c] * gradient_along; }
};

inline ColumnRecords column_records(const ParticleRecords& r, const AxisWeights aw[3], int a, int b, float dx) {
  const float m = r.mass;
  const float px = ((float)a - aw[0].f) * dx, py = ((float)b - aw[1].f) * dx;
  const float wab = aw[0].w[a] * aw[1].w[b];
  ColumnRecords column;
  column.in_plane = wab * r.base + (wab * px) * r.affine_x + (wab * py) * r.affine_y;
  column.along = wab * r.affine_z;
  column.gradient_in_plane = Lane4{m * aw[0].dw[a] * aw[1].w[b], m * aw[0].w[a] * aw[1].dw[b], 0.f, 0.f};
  column.gradient_along = Lane4{0.f, 0.f, m * wab, 0.f};
  column.z = &aw[2];
  column.dx = dx;
  return column;
}

}  // namespace fgs
