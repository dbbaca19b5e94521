// CPU (OpenMP) kernels of the damage-gradient partitioning (csrc/common/mpm_fragments.h). Like
// P2G they walk the particle cells in the 8 block-parity colours: cells of one colour never reach
// the same node, so nodes are written without atomics and the result does not depend on the
// number of threads. Per cell, what its particles read from the grid (nodal damage, which nodes
// are split and by which reference particle) is first copied into a small window over the 6x6x6
// nodes their stencils can reach, and fields A and B are summed there as 8-wide records (as P2G,
// csrc/mpm/mpm_cpu.cpp) before they are added to the grid once per cell.
#include <algorithm>
#include <cstring>
#include <omp.h>

#include "common/mpm_fragments.h"
#include "mpm/cpu_vector.h"
#include "mpm/p2g_records.h"
#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

constexpr int kSpan = kBlock + 2;  // nodes per axis the stencils of one cell's particles reach
constexpr int kSpanNodes = kSpan * kSpan * kSpan;

// Node coordinates of the first node of a cell's span (the first node of its block).
inline void span_origin(int block, const GridShape& s, int origin[3]) {
  origin[0] = (block / (s.by * s.bz)) * kBlock;
  origin[1] = ((block / s.bz) % s.by) * kBlock;
  origin[2] = (block % s.bz) * kBlock;
}

// Calls body(span index, node index within one grid) for every node of the span inside the grid.
template <class Body>
void for_span_nodes(const int origin[3], const GridShape& s, const Body& body) {
  const int hi[3] = {s.bx * kBlock, s.by * kBlock, s.bz * kBlock};
  for (int i = 0; i < kSpan && origin[0] + i < hi[0]; ++i) {
    const int ox = offset_x(origin[0] + i, s);
    for (int j = 0; j < kSpan && origin[1] + j < hi[1]; ++j) {
      const int oxy = ox + offset_y(origin[1] + j, s);
      for (int k = 0; k < kSpan && origin[2] + k < hi[2]; ++k)
        body((i * kSpan + j) * kSpan + k, (long long)(oxy + offset_z(origin[2] + k, s)));
    }
  }
}

// Runs body(cell) for every particle cell, colour after colour (cells of one colour in parallel).
template <class Body>
void for_cells_by_color(const BinsView& bins, const Body& body) {
#pragma omp parallel
  for (int color = 0; color < 8; ++color) {
#pragma omp for schedule(dynamic, 2)
    for (int ci = bins.color_start[color]; ci < bins.color_start[color + 1]; ++ci) body(bins.color_cells[ci]);
  }
}

}  // namespace

void fragment_reference_cpu(const BinsView& bins, const float* x, const MPMGeometry& geo, float mass_eps,
                            uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                            float* damage_gradient, int64_t* reference) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
  for_cells_by_color(bins, [&](int cell) {
    const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
    int origin[3];
    span_origin(block, s, origin);
    // Nodal damage D_i = sum w m D / sum w m over the span (0 without mass or outside the grid).
    float span_damage[kSpanNodes] = {};
    bool damaged = false;
    const float* mass = grid_mass + (long long)g * nodes;
    const float* damage = grid_damage + (long long)g * nodes;
    for_span_nodes(origin, s, [&](int w, long long node) {
      const float m = mass[node];
      if (!(m > mass_eps) || !(damage[node] > 0.f)) return;
      span_damage[w] = damage[node] / m;
      damaged = true;
    });
    int64_t span_keys[kSpanNodes] = {};  // the cell's largest keys, merged into the grid below
    bool any_key = false;
    for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
      const int q = bins.order[it];
      float* gq = damage_gradient + 3 * (long long)q;
      if (!damaged) {
        gq[0] = gq[1] = gq[2] = 0.f;
        continue;
      }
      AxisWeights aw[3];
      stencil_weights(x + 3 * (long long)q, geo, aw);
      const int l[3] = {aw[0].base - origin[0], aw[1].base - origin[1], aw[2].base - origin[2]};
      stencil_damage_gradient(aw, [&](int a, int b, int c) {  // D_i from the cell's span
        return span_damage[((l[0] + a) * kSpan + l[1] + b) * kSpan + l[2] + c];
      }, gq);
      const int64_t key = damage_key(gq, q);
      if (!key_is_split(key, split_bits)) continue;  // a key below the threshold splits no node
      any_key = true;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
          int64_t* column = span_keys + ((l[0] + a) * kSpan + l[1] + b) * kSpan + l[2];
          for (int c = 0; c < 3; ++c) column[c] = key > column[c] ? key : column[c];
        }
    }
    if (!any_key) return;
    int64_t* keys = reference + (long long)g * nodes;
    for_span_nodes(origin, s, [&](int w, long long node) {
      if (span_keys[w] > keys[node]) keys[node] = span_keys[w];
    });
  });
}

void fragment_split_nodes_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo,
                              const FragmentView& frag, GridArrays grid, uint8_t* split_block) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    const long long first = (long long)(touched[t] / n_blocks) * nodes + (long long)(touched[t] % n_blocks) * kBlockNodes;
    uint8_t any = 0;
    for (long long idx = first; idx < first + kBlockNodes; ++idx) {
      if (!key_is_split(frag.reference[idx], frag.split_bits)) continue;
      any = 1;
      grid.mass[idx] = 0.f;
      for (int d = 0; d < 3; ++d) {
        grid.momentum[3 * idx + d] = 0.f;
        grid.mass_gradient[3 * idx + d] = 0.f;
        grid.position_moment[3 * idx + d] = 0.f;
      }
    }
    split_block[touched[t]] = any;
  }
}

namespace {

// A cell's view of the partition and its fields A and B, per node of its span (per thread).
struct PartitionWindow {
  int32_t reference[kSpanNodes];  // reference particle of a split node, -1 where not split
  float reference_gradient[kSpanNodes][3];  // its damage gradient
  Record fields[2][kSpanNodes];   // A, B: [mass, momentum xyz, position moment xyz, unused]
  Lane4 gradient[2][kSpanNodes];  // A, B: mass gradient xyz (fields and gradient: split nodes only)
};

// Sums the cell's particles into the window's fields A and B at its split nodes (particles that
// reach none are skipped: split_particle and side_mask stay 0).
void partition_cell(const BinsView& bins, int cell, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                    const FragmentView& frag, const int origin[3], PartitionWindow& win, uint8_t* split_particle,
                    int32_t* side_mask) {
  const float dx = geo.dx;
  for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
    const int q = bins.order[it];
    AxisWeights aw[3];
    stencil_weights(p.x + 3 * (long long)q, geo, aw);
    const int lx = aw[0].base - origin[0], ly = aw[1].base - origin[1], lz = aw[2].base - origin[2];
    // Most particles of a cell near a crack reach no split node, and then need no APIC matrix.
    bool reaches_split = false;
    for (int a = 0; a < 3 && !reaches_split; ++a)
      for (int b = 0; b < 3; ++b) {
        const int32_t* column = win.reference + ((lx + a) * kSpan + ly + b) * kSpan + lz;
        reaches_split |= (column[0] & column[1] & column[2]) >= 0;  // the AND of -1s is -1: some node >= 0
      }
    split_particle[q] = reaches_split ? 1 : 0;
    if (!reaches_split) continue;
    const float m = p.mass[q];
    float A[9];
    apic_affine(p.C + 9 * (long long)q, p.stress + 9 * (long long)q, m, p.rest_volume[q], dt, geo.inv_dx, A);
    const float* dq = frag.damage_gradient + 3 * (long long)q;
    const float damage_gradient[3] = {dq[0], dq[1], dq[2]};  // in registers: the window stores may alias dq
    uint32_t mask = 0;
    // P2G's records (csrc/mpm/p2g_records.h) without the damage lane.
    const ParticleRecords records = particle_records(m, p.v + 3 * (long long)q, A, 0.f);
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        const ColumnRecords column = column_records(records, aw, a, b, dx);
        const int row = ((lx + a) * kSpan + ly + b) * kSpan + lz;
        for (int c = 0; c < 3; ++c) {
          if (win.reference[row + c] < 0) continue;
          const int side = sides_differ(damage_gradient, win.reference_gradient[row + c]) ? 1 : 0;
          if (side) mask |= side_bit(a, b, c);
          win.fields[side][row + c] += column.node_record(c);
          win.gradient[side][row + c] += column.node_gradient(c);
        }
      }
    }
    side_mask[q] = (int32_t)mask;
  }
}

}  // namespace

void fragment_p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                      const FragmentView& frag, GridArrays grid, uint8_t* split_particle, int32_t* side_mask) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
#pragma omp parallel
  {
    PartitionWindow win;  // per thread
    for (int color = 0; color < 8; ++color) {
#pragma omp for schedule(dynamic, 2)
      for (int ci = bins.color_start[color]; ci < bins.color_start[color + 1]; ++ci) {
        const int cell = bins.color_cells[ci];
        const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
        int origin[3];
        span_origin(block, s, origin);
        const int64_t* keys = frag.reference + (long long)g * nodes;
        bool any_split = false;
        std::fill(win.reference, win.reference + kSpanNodes, -1);
        for_span_nodes(origin, s, [&](int w, long long node) {
          if (!key_is_split(keys[node], frag.split_bits)) return;
          const long long ref = key_particle(keys[node]);
          win.reference[w] = (int32_t)ref;
          for (int d = 0; d < 3; ++d) win.reference_gradient[w][d] = frag.damage_gradient[3 * ref + d];
          for (int side = 0; side < 2; ++side) {  // the fields are only summed and read at split nodes
            win.fields[side][w] = Record{};
            win.gradient[side][w] = Lane4{};
          }
          any_split = true;
        });
        if (!any_split) continue;  // no particle of the cell reaches a split node (split_particle stays 0)
        partition_cell(bins, cell, p, geo, dt, frag, origin, win, split_particle, side_mask);
        for_span_nodes(origin, s, [&](int w, long long node) {
          if (win.reference[w] < 0) return;
          for (int side = 0; side < 2; ++side) {
            const Record r = win.fields[side][w];
            if (side == 1 && r[0] == 0.f) continue;  // no particle on side B here (B is zero on entry)
            const long long idx = (long long)(g + side * frag.n_fields) * nodes + node;
            const Lane4 gradient = win.gradient[side][w];
            grid.mass[idx] += r[0];
            for (int d = 0; d < 3; ++d) {
              grid.momentum[3 * idx + d] += r[1 + d];
              grid.position_moment[3 * idx + d] += r[4 + d];
              grid.mass_gradient[3 * idx + d] += gradient[d];
            }
          }
        });
      }
    }
  }
}

void fragment_clear_cpu(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_keys; ++t) {
    const long long first = (long long)(keys[t] / n_blocks) * nodes + (long long)(keys[t] % n_blocks) * kBlockNodes;
    std::memset(grid.mass + first, 0, sizeof(float) * kBlockNodes);
    std::memset(grid.momentum + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    std::memset(grid.velocity + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    std::memset(grid.mass_gradient + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    std::memset(grid.position_moment + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
  }
}

}  // namespace fgs
