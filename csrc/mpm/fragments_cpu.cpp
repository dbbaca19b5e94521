// CPU (OpenMP) kernels of the damage-gradient partitioning (csrc/common/mpm_fragments.h). Like
// P2G they walk the particle cells in the 8 block-parity colours: cells of one colour never reach
// the same node, so nodes are written without atomics and the result does not depend on the
// number of threads. Per cell, what its particles read from the grid (nodal damage, which nodes
// are split and by which reference particle) is first copied into a small window over the 6x6x6
// nodes their stencils can reach, and side B is summed there as 8-wide records (as P2G,
// csrc/mpm/mpm_cpu.cpp) before it is added to the grid once per cell; field A, which holds P2G's
// sum, then becomes that sum minus B (fragment_merge_cpu).
#include <algorithm>
#include <cstring>
#include <omp.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

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
  block_coords(block, s, origin);
  for (int d = 0; d < 3; ++d) origin[d] *= kBlock;
}

// Bit l set where lane l of v is < 0.
inline uint32_t negative_lanes(Lane4 v) {
  const auto negative = v < 0.f;  // lanes: -1 where true, 0 elsewhere
#if defined(__SSE__)
  return (uint32_t)_mm_movemask_ps((__m128)negative);  // the sign bits of the lanes
#else
  return (uint32_t)(negative[0] & 1) | (uint32_t)(negative[1] & 2) | (uint32_t)(negative[2] & 4) |
         (uint32_t)(negative[3] & 8);
#endif
}

inline Lane4 load_row(const float* row) {  // nodes c = 0, 1, 2 of a stencil row (lane 3: the next node)
  Lane4 v;
  __builtin_memcpy(&v, row, sizeof(v));
  return v;
}

// Index in the span of node (l0 + a, l1 + b, l2): the first of the 3 nodes along z of row (a, b) of
// the stencil whose first node is l.
inline int span_row(const int l[3], int a, int b) { return ((l[0] + a) * kSpan + l[1] + b) * kSpan + l[2]; }

// True if some node of a particle's stencil (its first node at l in the span) has a value > 0 in
// `span` (kSpanNodes + 1 floats, all >= 0; the last one is read, not used).
inline bool stencil_reaches_positive(const float* span, const int l[3]) {
  Lane4 highest = {0.f, 0.f, 0.f, 0.f};
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const Lane4 row = load_row(span + span_row(l, a, b));
      highest = row > highest ? row : highest;
    }
  return (negative_lanes(-highest) & 7u) != 0;  // lanes 0-2: the stencil's nodes
}

// Index in [0, 64) of the stencil whose first node is l in [0, 4)^3 of a cell's span (the
// stencils a cell's particles can have).
inline int stencil_slot(const int l[3]) { return (l[0] * kBlock + l[1]) * kBlock + l[2]; }

// Calls body(l) for the first node l in [0, 4)^3 of each of the 64 stencils of a cell's particles.
template <class Body>
void for_stencil_origins(const Body& body) {
  for (int l0 = 0; l0 < kBlock; ++l0)
    for (int l1 = 0; l1 < kBlock; ++l1)
      for (int l2 = 0; l2 < kBlock; ++l2) {
        const int l[3] = {l0, l1, l2};
        body(l);
      }
}

// Bit stencil_slot(l) set where the stencil with first node l reaches a value > 0 in `span`:
// computed once per cell instead of once per particle.
inline uint64_t stencils_reaching_positive(const float* span) {
  uint64_t reaching = 0;
  for_stencil_origins([&](const int l[3]) {
    if (stencil_reaches_positive(span, l)) reaching |= 1ull << stencil_slot(l);
  });
  return reaching;
}

inline bool stencil_bit(uint64_t table, const int l[3]) { return (table >> stencil_slot(l)) & 1ull; }

// Damage gradient sum_i D_i grad w_ip of a particle whose stencil starts at l in the span: the
// formula of particle_damage_gradient (csrc/common/mpm_fragments.h) with 4-wide rows. Per (x, y)
// column of the stencil, its 3 nodes along z are one 4-wide load (the fourth lane, the next node of
// the span, meets a zero weight), scaled by the column's x and y weight products and summed into
// three accumulators; the z weights are applied once at the end. Tested against the torch twin.
inline void span_damage_gradient(const float* span, const int l[3], const AxisWeights aw[3], float out[3]) {
  Lane4 sum_x[3], sum_y[3], sum_z[3];  // per x layer a: three short chains instead of one long one
  for (int a = 0; a < 3; ++a) {
    sum_x[a] = sum_y[a] = sum_z[a] = Lane4{0.f, 0.f, 0.f, 0.f};
    for (int b = 0; b < 3; ++b) {
      const Lane4 row = load_row(span + span_row(l, a, b));
      sum_x[a] += (aw[0].dw[a] * aw[1].w[b]) * row;
      sum_y[a] += (aw[0].w[a] * aw[1].dw[b]) * row;
      sum_z[a] += (aw[0].w[a] * aw[1].w[b]) * row;
    }
  }
  const Lane4 along_x = (sum_x[0] + sum_x[1]) + sum_x[2], along_y = (sum_y[0] + sum_y[1]) + sum_y[2],
              along_z = (sum_z[0] + sum_z[1]) + sum_z[2];
  const Lane4 w_z = {aw[2].w[0], aw[2].w[1], aw[2].w[2], 0.f};
  const Lane4 dw_z = {aw[2].dw[0], aw[2].dw[1], aw[2].dw[2], 0.f};
  const Lane4 x_terms = along_x * w_z, y_terms = along_y * w_z, z_terms = along_z * dw_z;
  out[0] = (x_terms[0] + x_terms[1]) + x_terms[2];
  out[1] = (y_terms[0] + y_terms[1]) + y_terms[2];
  out[2] = (z_terms[0] + z_terms[1]) + z_terms[2];
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

// True if a stencil starting at l (relative to the cell's block origin) starts in the cell's
// block: then its 27 nodes lie in the cell's span and stencil_slot(l) < 64.
inline bool starts_in_block(const int l[3]) {
  return ((unsigned)l[0] < (unsigned)kBlock) & ((unsigned)l[1] < (unsigned)kBlock) & ((unsigned)l[2] < (unsigned)kBlock);
}

// Keeps the smaller of two indices, -1 meaning none.
inline long long first_of(long long a, long long b) { return a < 0 ? b : (b < 0 || a < b ? a : b); }

// Runs body(cell) for every particle cell, colour after colour (cells of one colour in parallel);
// body returns the smallest misplaced particle of its cell or -1, and so does this.
template <class Body>
long long for_cells_by_color(const BinsView& bins, const Body& body) {
  long long misplaced = -1;
#pragma omp parallel
  {
    long long mine = -1;
    for (int color = 0; color < 8; ++color) {
#pragma omp for schedule(dynamic, 2)
      for (int ci = bins.color_start[color]; ci < bins.color_start[color + 1]; ++ci)
        mine = first_of(mine, body(bins.color_cells[ci]));
    }
#pragma omp critical(fgs_fragments_misplaced)
    misplaced = first_of(misplaced, mine);
  }
  return misplaced;
}

}  // namespace

BoundReport fragment_reference_cpu(const BinsView& bins, const float* x, const MPMGeometry& geo, float mass_eps,
                                   uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                                   const DirectionView& directions, float* damage_gradient, int64_t* reference) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
  BoundReport report;
  report.misplaced = for_cells_by_color(bins, [&](int cell) -> long long {
    const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
    int origin[3];
    span_origin(block, s, origin);
    // Nodal damage D_i = sum w m D / sum w m over the span (0 without mass or outside the grid).
    float span_damage[kSpanNodes + 1] = {};  // + 1: the 4-wide row loads read one node past the last
    bool damaged = false;
    const float* mass = grid_mass + (long long)g * nodes;
    const float* damage = grid_damage + (long long)g * nodes;
    for_span_nodes(origin, s, [&](int w, long long node) {
      const float m = mass[node];
      if (!(m > mass_eps) || !(damage[node] > 0.f)) return;
      span_damage[w] = damage[node] / m;
      damaged = true;
    });
    if (!damaged) {  // no damage anywhere in reach of the cell's particles: every gradient is +0
      for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
        float* gq = damage_gradient + 3 * (long long)bins.order[it];
        gq[0] = gq[1] = gq[2] = 0.f;
      }
      return -1;
    }
    // A particle whose stencil reaches no damaged node has the gradient +0 exactly (the sum below,
    // of zeros), and skips it.
    const uint64_t reaches_damage = stencils_reaching_positive(span_damage);
    // Largest key per stencil origin l in [0, 4)^3 (the particles of one origin reach the same 27
    // nodes): one maximum per particle here, spread to the span's nodes once per cell below.
    int64_t origin_keys[kBlockNodes] = {};  // by stencil_slot
    bool any_key = false;
    long long misplaced = -1;
    for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
      const int q = bins.order[it];
      float* gq = damage_gradient + 3 * (long long)q;
      AxisWeights aw[3];
      stencil_weights(x + 3 * (long long)q, geo, aw);
      const int l[3] = {aw[0].base - origin[0], aw[1].base - origin[1], aw[2].base - origin[2]};
      if (!starts_in_block(l)) {  // outside the span: skipped (P2G reports it too)
        gq[0] = gq[1] = gq[2] = 0.f;
        misplaced = first_of(misplaced, q);
        continue;
      }
      if (!stencil_bit(reaches_damage, l)) {
        gq[0] = gq[1] = gq[2] = 0.f;
        continue;
      }
      span_damage_gradient(span_damage, l, aw, gq);  // D_i from the cell's span
      apply_split_direction(directions, q, gq);
      const int64_t key = damage_key(gq, q);
      if (!key_is_split(key, split_bits)) continue;  // a key below the threshold splits no node
      any_key = true;
      int64_t& slot = origin_keys[stencil_slot(l)];
      slot = key > slot ? key : slot;
    }
    if (!any_key) return misplaced;
    int64_t span_keys[kSpanNodes] = {};  // the cell's largest key per node of its span
    for_stencil_origins([&](const int l[3]) {
      const int64_t key = origin_keys[stencil_slot(l)];
      if (key == 0) return;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
          int64_t* column = span_keys + span_row(l, a, b);
          for (int c = 0; c < 3; ++c) column[c] = key > column[c] ? key : column[c];
        }
    });
    int64_t* keys = reference + (long long)g * nodes;
    for_span_nodes(origin, s, [&](int w, long long node) {
      if (span_keys[w] > keys[node]) keys[node] = span_keys[w];
    });
    return misplaced;
  });
  return report;
}

namespace {

// A cell's view of the partition and its field B, per node of its span (per thread). The
// reference gradients are kept as three arrays, zero where a node is not split, so that the side
// tests of a stencil row (3 nodes along z) are one 4-wide dot product: at a node that is not split
// the dot product is 0, which is "side A", as at a split node where it is not negative.
struct PartitionWindow {
  float reference_gradient[3][kSpanNodes + 1];  // grad D of each split node's reference, 0 elsewhere
  float split[kSpanNodes + 1];                  // 1 at split nodes, 0 elsewhere
  Record field_b[kSpanNodes];                   // side B: [mass, momentum xyz, position moment xyz, unused]
  Lane4 gradient_b[kSpanNodes];                 // side B: mass gradient xyz (fields: split nodes only)
};

// Side mask (side_bit set where grad D_p . grad D_ref < 0) of a particle with stencil origin l in
// the span.
inline uint32_t side_mask_in_window(const PartitionWindow& win, const int l[3], const float gq[3]) {
  uint32_t mask = 0;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const int row = span_row(l, a, b);
      const Lane4 dot = (gq[0] * load_row(win.reference_gradient[0] + row) +
                         gq[1] * load_row(win.reference_gradient[1] + row)) +
                        gq[2] * load_row(win.reference_gradient[2] + row);
      mask |= (negative_lanes(dot) & 7u) << (9 * a + 3 * b);
    }
  return mask;
}

// Sums the side-B share of the cell's particles into the window (particles that reach no split
// node, or are on side A at every split node they reach, add nothing; split_particle and
// side_mask record what each particle found, written for every particle of the cell). Returns
// the smallest particle whose stencil does not start in the cell's block (skipped), or -1.
long long partition_cell(const BinsView& bins, int cell, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                    const FragmentView& frag, const int origin[3], PartitionWindow& win, uint8_t* split_particle,
                    int32_t* side_mask) {
  const float dx = geo.dx;
  const uint64_t reaches_split = stencils_reaching_positive(win.split);
  long long misplaced = -1;
  for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
    const int q = bins.order[it];
    // The stencil's first node exactly as P2G and G2P compute it (the same expression); its
    // weights only for particles on side B somewhere (below).
    const float* xq = p.x + 3 * (long long)q;
    int base[3];
    stencil_base(xq, geo, base);
    const int l[3] = {base[0] - origin[0], base[1] - origin[1], base[2] - origin[2]};
    if (!starts_in_block(l)) {  // outside the window: skipped (P2G reports it too)
      split_particle[q] = 0;
      side_mask[q] = 0;
      misplaced = first_of(misplaced, q);
      continue;
    }
    if (!stencil_bit(reaches_split, l)) {  // no split node in reach: side A everywhere
      split_particle[q] = 0;
      side_mask[q] = 0;
      continue;
    }
    split_particle[q] = 1;
    const float* dq = frag.damage_gradient + 3 * (long long)q;
    const float damage_gradient[3] = {dq[0], dq[1], dq[2]};
    // A zero gradient (no damage in reach) is on side A everywhere: no dot products.
    const bool has_gradient = damage_gradient[0] != 0.f || damage_gradient[1] != 0.f || damage_gradient[2] != 0.f;
    const uint32_t mask = has_gradient ? side_mask_in_window(win, l, damage_gradient) : 0u;
    side_mask[q] = (int32_t)mask;
    if (mask == 0) continue;  // side A wherever it meets a split node: P2G's field A already holds it
    AxisWeights aw[3];
    stencil_weights(xq, geo, aw);
    const float m = p.mass[q];
    float A[9];
    apic_affine(p.C + 9 * (long long)q, p.stress + 9 * (long long)q, m, p.rest_volume[q], dt, geo.inv_dx, A);
    // P2G's records (csrc/mpm/p2g_records.h) without the damage lane, at the side-B nodes only.
    const ParticleRecords records = particle_records(m, p.v + 3 * (long long)q, A, 0.f);
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        const uint32_t column_bits = (mask >> (9 * a + 3 * b)) & 7u;
        if (column_bits == 0) continue;
        const ColumnRecords column = column_records(records, aw, a, b, dx);
        const int row = span_row(l, a, b);
        for (int c = 0; c < 3; ++c) {
          if (!(column_bits & (1u << c))) continue;
          win.field_b[row + c] += column.node_record(c);
          win.gradient_b[row + c] += column.node_gradient(c);
        }
      }
    }
  }
  return misplaced;
}

}  // namespace

BoundReport fragment_p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                             const FragmentView& frag, GridArrays grid, uint8_t* split_particle, int32_t* side_mask,
                             uint8_t* side_b_block) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
  BoundReport report;
#pragma omp parallel
  {
    PartitionWindow win;  // per thread
    long long misplaced = -1, bad_reference = -1;
    for (int color = 0; color < 8; ++color) {
#pragma omp for schedule(dynamic, 2)
      for (int ci = bins.color_start[color]; ci < bins.color_start[color + 1]; ++ci) {
        const int cell = bins.color_cells[ci];
        const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
        int origin[3];
        span_origin(block, s, origin);
        const int64_t* keys = frag.reference + (long long)g * nodes;
        bool any_split = false;
        for (int d = 0; d < 3; ++d) std::fill_n(win.reference_gradient[d], kSpanNodes + 1, 0.f);
        std::fill_n(win.split, kSpanNodes + 1, 0.f);
        for_span_nodes(origin, s, [&](int w, long long node) {
          if (!key_is_split(keys[node], frag.split_bits)) return;
          const long long ref = key_particle(keys[node]);
          if (ref >= bins.n_particles) {  // a key from another particle set: the node is not split
            bad_reference = first_of(bad_reference, (long long)g * nodes + node);
            return;
          }
          for (int d = 0; d < 3; ++d) win.reference_gradient[d][w] = frag.damage_gradient[3 * ref + d];
          win.split[w] = 1.f;
          win.field_b[w] = Record{};  // field B is only summed and read at split nodes
          win.gradient_b[w] = Lane4{};
          any_split = true;
        });
        if (!any_split) {  // no particle of the cell reaches a split node
          for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
            split_particle[bins.order[it]] = 0;
            side_mask[bins.order[it]] = 0;
          }
          continue;
        }
        misplaced = first_of(misplaced, partition_cell(bins, cell, p, geo, dt, frag, origin, win, split_particle,
                                                       side_mask));
        // Cells of one colour span disjoint blocks, so the flags are written without races.
        uint8_t* b_blocks = side_b_block + (long long)g * n_blocks;
        for_span_nodes(origin, s, [&](int w, long long node) {
          if (win.split[w] == 0.f) return;
          const Record r = win.field_b[w];
          if (r[0] == 0.f) return;  // no particle on side B here (B is zero on entry)
          const long long idx = (long long)(g + frag.n_fields) * nodes + node;
          const Lane4 gradient = win.gradient_b[w];
          grid.mass[idx] += r[0];
          for (int d = 0; d < 3; ++d) {
            grid.momentum[3 * idx + d] += r[1 + d];
            grid.position_moment[3 * idx + d] += r[4 + d];
            grid.mass_gradient[3 * idx + d] += gradient[d];
          }
          b_blocks[node / kBlockNodes] = 1;
        });
      }
    }
#pragma omp critical(fgs_fragments_report)
    {
      report.misplaced = first_of(report.misplaced, misplaced);
      report.bad_reference = first_of(report.bad_reference, bad_reference);
    }
  }
  return report;
}

void fragment_merge_cpu(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
  const long long field_b = (long long)geo.n_grids * nodes;
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_keys; ++t) {
    const long long first = (long long)(keys[t] / n_blocks) * nodes + (long long)(keys[t] % n_blocks) * kBlockNodes;
    for (long long idx = first; idx < first + kBlockNodes; ++idx)
      if (grid.mass[idx + field_b] != 0.f)
        split_node_fields(idx, idx + field_b, grid.mass, grid.momentum, grid.mass_gradient, grid.position_moment);
  }
}

void fragment_field_blocks_cpu(const int32_t* touched, int n_touched, const int32_t* contact_blocks, int n_contact,
                               const int32_t* split_keys, int n_split, int n_blocks, int n_grids,
                               std::vector<int32_t>& field_touched, std::vector<int32_t>& field_contact) {
  field_touched.assign(touched, touched + n_touched);
  for (int t = 0; t < n_split; ++t) field_touched.push_back(split_keys[t] + n_grids * n_blocks);
  field_contact.assign(contact_blocks, contact_blocks + n_contact);
  for (int t = 0; t < n_split; ++t) field_contact.push_back(split_keys[t] % n_blocks);
  std::sort(field_contact.begin(), field_contact.end());
  field_contact.erase(std::unique(field_contact.begin(), field_contact.end()), field_contact.end());
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
