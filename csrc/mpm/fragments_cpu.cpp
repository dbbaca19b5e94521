// CPU (OpenMP) kernels of the damage-gradient partitioning (csrc/common/mpm_fragments.h). Like
// P2G they walk the particle cells in the 8 block-parity colours: cells of one colour never reach
// the same node, so nodes are written without atomics and the result does not depend on the
// number of threads.
#include <cstring>
#include <omp.h>

#include "common/mpm_fragments.h"
#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

// True if pred(node index within one grid) holds for some node of the 6x6x6 span the stencils of
// a cell's particles can reach (its block's base nodes + 0..2).
template <class Pred>
bool cell_span_any(int block, const GridShape& s, const Pred& pred) {
  const int bi = block / (s.by * s.bz), bj = (block / s.bz) % s.by, bk = block % s.bz;
  const int hi[3] = {s.bx * kBlock - 1, s.by * kBlock - 1, s.bz * kBlock - 1};
  for (int i = bi * kBlock; i <= bi * kBlock + kBlock + 1 && i <= hi[0]; ++i) {
    const int ox = offset_x(i, s);
    for (int j = bj * kBlock; j <= bj * kBlock + kBlock + 1 && j <= hi[1]; ++j) {
      const int oxy = ox + offset_y(j, s);
      for (int k = bk * kBlock; k <= bk * kBlock + kBlock + 1 && k <= hi[2]; ++k)
        if (pred((long long)(oxy + offset_z(k, s)))) return true;
    }
  }
  return false;
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
    const float* damage = grid_damage + (long long)g * nodes;
    const bool damaged = cell_span_any(block, s, [&](long long node) { return damage[node] > 0.f; });
    int64_t* keys = reference + (long long)g * nodes;
    for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
      const int q = bins.order[it];
      float* gq = damage_gradient + 3 * (long long)q;
      if (!damaged) {
        gq[0] = gq[1] = gq[2] = 0.f;
        continue;
      }
      particle_damage_gradient(x + 3 * (long long)q, g, geo, grid_mass, grid_damage, mass_eps, gq);
      const int64_t key = damage_key(gq, q);
      if (!key_is_split(key, split_bits)) continue;  // a key below the threshold splits no node
      AxisWeights aw[3];
      stencil_weights(x + 3 * (long long)q, geo, aw);
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
          for (int c = 0; c < 3; ++c) {
            int64_t& slot = keys[node_index(aw[0].base + a, aw[1].base + b, aw[2].base + c, s)];
            if (key > slot) slot = key;
          }
    }
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

void fragment_p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                      const FragmentView& frag, GridArrays grid, uint8_t* split_particle) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
  for_cells_by_color(bins, [&](int cell) {
    const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
    const int64_t* keys = frag.reference + (long long)g * nodes;
    if (!cell_span_any(block, s, [&](long long node) { return key_is_split(keys[node], frag.split_bits); })) return;
    for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
      const int q = bins.order[it];
      AxisWeights aw[3];
      stencil_weights(p.x + 3 * (long long)q, geo, aw);
      // The split nodes of q's stencil first: most particles of a cell near a crack reach none,
      // and then need no APIC matrix either.
      long long split_node[27];
      int split_abc[27], n_split = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
          for (int c = 0; c < 3; ++c) {
            const long long node = node_index(aw[0].base + a, aw[1].base + b, aw[2].base + c, s);
            if (!key_is_split(keys[node], frag.split_bits)) continue;
            split_node[n_split] = node;
            split_abc[n_split++] = 9 * a + 3 * b + c;
          }
      split_particle[q] = n_split > 0 ? 1 : 0;
      if (n_split == 0) continue;
      const float m = p.mass[q];
      const float mv[3] = {m * p.v[3 * q], m * p.v[3 * q + 1], m * p.v[3 * q + 2]};
      float A[9];
      apic_affine(p.C + 9 * (long long)q, p.stress + 9 * (long long)q, m, p.rest_volume[q], dt, geo.inv_dx, A);
      for (int k = 0; k < n_split; ++k) {
        const long long node = split_node[k];
        const int a = split_abc[k] / 9, b = (split_abc[k] / 3) % 3, c = split_abc[k] % 3;
        const long long idx = (long long)fragment_field(frag, g, q, node, nodes) * nodes + node;
        p2g_node_add(aw, a, b, c, m, mv, A, geo.dx, grid.mass + idx, grid.momentum + 3 * idx,
                     grid.mass_gradient + 3 * idx, grid.position_moment + 3 * idx);
      }
    }
  });
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
