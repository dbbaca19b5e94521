// CPU (OpenMP) MPM kernels. The per-particle and per-node math comes from the shared headers;
// this file only decides how to loop. P2G processes particle blocks in 8 colours so that blocks
// running at the same time never write the same grid node: no atomics, and the result does not
// depend on the number of threads.
#include <algorithm>
#include <atomic>
#include <omp.h>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include "mpm/constitutive_batch.h"
#include "mpm/cpu_vector.h"
#include "mpm/p2g_records.h"
#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

inline int block_color(int block, const GridShape& s) {
  int ijk[3];
  block_coords(block, s, ijk);
  return ((ijk[0] & 1) << 2) | ((ijk[1] & 1) << 1) | (ijk[2] & 1);
}

}  // namespace

namespace {

// Range [begin, end) of part `t` of `parts` near-equal parts of [0, n).
inline void split_range(long long n, int parts, int t, long long* begin, long long* end) {
  *begin = n * t / parts;
  *end = n * (t + 1) / parts;
}

// Writes, in ascending order, every i in [0, n) with keep(i) to out (resized here): each thread
// counts its part, a prefix over the parts places them. The result does not depend on the
// number of threads.
template <class Keep>
void parallel_select(long long n, std::vector<int32_t>* out, const Keep& keep) {
  const int parts = omp_get_max_threads();
  std::vector<long long> part_start(parts + 1, 0);
#pragma omp parallel num_threads(parts)
  {
    const int t = omp_get_thread_num(), team = omp_get_num_threads();
    long long begin, end, kept = 0;
    split_range(n, team, t, &begin, &end);
    for (long long i = begin; i < end; ++i) kept += keep(i) ? 1 : 0;
    part_start[t + 1] = kept;
#pragma omp barrier
#pragma omp single
    {
      for (int u = team; u < parts; ++u) part_start[u + 1] = 0;
      for (int u = 0; u < parts; ++u) part_start[u + 1] += part_start[u];
      out->resize(part_start[parts]);
    }
    long long cursor = part_start[t];
    for (long long i = begin; i < end; ++i)
      if (keep(i)) (*out)[cursor++] = (int32_t)i;
  }
}

}  // namespace

// Counting sort of the particles by (grid, block), in parallel and stable: thread t counts
// and later scatters its own range of particles, and a prefix over (key, thread) gives each
// thread its slots, so `order` is the same as a serial stable sort for any number of threads.
long long bin_particles_cpu(const float* x, const int32_t* grid_id, long long n,
                            const MPMGeometry& geo, ParticleBins* bins) {
  const GridShape& s = geo.shape;
  const int n_blocks = s.blocks();
  const long long n_keys = (long long)geo.n_grids * n_blocks;
  const int limit[3] = {s.bx * kBlock - 3, s.by * kBlock - 3, s.bz * kBlock - 3};
  const int parts = omp_get_max_threads();
  std::unique_ptr<int32_t[]> key(new int32_t[n]);  // every entry written below
  std::unique_ptr<uint8_t[]> reach(new uint8_t[n]);  // bit d set: the stencil reaches the next block along axis d
  // slot[t * n_keys + k]: particles of key k in thread t's range, then the first slot they take.
  std::vector<int32_t> slot((size_t)parts * n_keys, 0);
  // key_reach[t * n_keys + k]: the reach bits of thread t's particles of key k, OR-ed.
  std::vector<uint8_t> key_reach((size_t)parts * n_keys, 0);
  std::vector<long long> chunk_total(parts + 1, 0), chunk_cells(parts + 1, 0);
  long long bad = -1;
  int counted_by = parts;  // the team that counted: its ranges and slot rows place the particles below
#pragma omp parallel num_threads(parts) reduction(max : bad)
  {
    const int t = omp_get_thread_num(), team = omp_get_num_threads();
    long long begin, end;
    split_range(n, team, t, &begin, &end);
    int32_t* count = slot.data() + (size_t)t * n_keys;
    uint8_t* run_reach = key_reach.data() + (size_t)t * n_keys;
    for (long long p = begin; p < end; ++p) {
      int base[3];
      bool ok = grid_id[p] >= 0 && grid_id[p] < geo.n_grids;
      uint8_t r = 0;
      for (int d = 0; d < 3; ++d) {
        const float X = grid_coordinate(x[3 * p + d], geo.lower[d], geo.inv_dx);  // as P2G's stencil
        ok = ok && X >= 0.5f && X < (float)limit[d] + 0.5f;  // also false for NaN
        base[d] = ok ? axis_base(X) : 0;
        if ((base[d] & (kBlock - 1)) >= kBlock - 2) r |= (uint8_t)(1 << d);
      }
      if (!ok) {
        bad = std::max(bad, p);
        key[p] = 0;
        reach[p] = 0;
        continue;
      }
      const int block = ((base[0] >> kBlockBits) * s.by + (base[1] >> kBlockBits)) * s.bz + (base[2] >> kBlockBits);
      key[p] = grid_id[p] * n_blocks + block;
      reach[p] = r;
    }
    // Counted run by run: neighbouring particles mostly share a key (spatially ordered input),
    // and a counter kept in a register avoids a load-store chain through count[].
    for (long long p = begin; p < end;) {
      const int32_t k = key[p];
      uint8_t r = reach[p];
      long long run_end = p + 1;
      for (; run_end < end && key[run_end] == k; ++run_end) r |= reach[run_end];
      count[k] += (int32_t)(run_end - p);
      run_reach[k] |= r;
      p = run_end;
    }
#pragma omp barrier
    // Totals per key over the threads, then the prefix over keys (by key chunks).
    long long k_begin, k_end;
    split_range(n_keys, team, t, &k_begin, &k_end);
    long long chunk_sum = 0, chunk_nonempty = 0;
    for (long long k = k_begin; k < k_end; ++k) {
      long long key_count = 0;
      for (int u = 0; u < team; ++u) key_count += slot[(size_t)u * n_keys + k];
      chunk_sum += key_count;
      chunk_nonempty += key_count > 0 ? 1 : 0;
    }
    chunk_total[t + 1] = chunk_sum;
    chunk_cells[t + 1] = chunk_nonempty;
#pragma omp barrier
#pragma omp single
    {
      counted_by = team;
      for (int u = 0; u < team; ++u) {
        chunk_total[u + 1] += chunk_total[u];
        chunk_cells[u + 1] += chunk_cells[u];
      }
      bins->cell_key.resize(chunk_cells[team]);
      bins->cell_start.resize(chunk_cells[team] + 1);
    }
    // Slots, and the non-empty keys ("cells") with their first slot, in key order.
    long long running = chunk_total[t], cell = chunk_cells[t];
    for (long long k = k_begin; k < k_end; ++k) {
      const long long first = running;
      for (int u = 0; u < team; ++u) {
        const int32_t c = slot[(size_t)u * n_keys + k];
        slot[(size_t)u * n_keys + k] = (int32_t)running;
        running += c;
      }
      if (running > first) {
        bins->cell_key[cell] = (int32_t)k;
        bins->cell_start[cell] = (int32_t)first;
        ++cell;
      }
    }
  }
  if (bad >= 0) return bad;
  const int n_cells = (int)bins->cell_key.size();
  bins->cell_start[n_cells] = (int32_t)n;
  bins->order.resize(n);
  // Each range of the counting team is scattered with its own slots, whatever team runs this
  // region (a range counted by one thread must not be placed with another range's slots).
#pragma omp parallel num_threads(counted_by)
  for (int t = omp_get_thread_num(); t < counted_by; t += omp_get_num_threads()) {
    long long begin, end;
    split_range(n, counted_by, t, &begin, &end);
    int32_t* cursor = slot.data() + (size_t)t * n_keys;
    int32_t* order = bins->order.data();
    for (long long p = begin; p < end;) {  // run by run, as the counting
      const int32_t k = key[p];
      int32_t next = cursor[k];
      long long q = p;
      for (; q < end && key[q] == k; ++q) order[next++] = (int32_t)q;
      cursor[k] = next;
      p = q;
    }
  }

  // The blocks the cells' stencils touch: the cell's block and the upper neighbours its
  // particles reach. Several cells may mark one block, all with the same value (relaxed atomic
  // stores: no ordering needed, the result is a set).
  std::vector<uint8_t> touched_mark(n_keys, 0);
#pragma omp parallel for schedule(static)
  for (int c = 0; c < n_cells; ++c) {
    const int k = bins->cell_key[c];
    uint8_t r = 0;
    for (int u = 0; u < counted_by; ++u) r |= key_reach[(size_t)u * n_keys + k];
    const int g = k / n_blocks;
    int b[3];
    block_coords(k % n_blocks, s, b);
    for (int di = 0; di <= ((r >> 0) & 1); ++di)
      for (int dj = 0; dj <= ((r >> 1) & 1); ++dj)
        for (int dk = 0; dk <= ((r >> 2) & 1); ++dk)
          std::atomic_ref<uint8_t>(
              touched_mark[(long long)g * n_blocks + ((b[0] + di) * s.by + b[1] + dj) * s.bz + b[2] + dk])
              .store(1, std::memory_order_relaxed);
  }
  parallel_select(n_keys, &bins->touched, [&](long long k) { return touched_mark[k] != 0; });
  bins->contact_blocks.clear();
  if (geo.n_grids >= 2) {
    parallel_select(n_blocks, &bins->contact_blocks, [&](long long b) {
      int grids_here = 0;
      for (int g = 0; g < geo.n_grids; ++g) grids_here += touched_mark[(long long)g * n_blocks + b];
      return grids_here >= 2;
    });
  }

  // Cells grouped by block parity colour, ascending inside each colour.
  bins->color_start.assign(9, 0);
  std::vector<uint8_t> colors(n_cells);
  for (int c = 0; c < n_cells; ++c) {
    colors[c] = (uint8_t)block_color(bins->cell_key[c] % n_blocks, s);
    ++bins->color_start[colors[c] + 1];
  }
  for (int c = 0; c < 8; ++c) bins->color_start[c + 1] += bins->color_start[c];
  bins->color_cells.resize(n_cells);
  {
    std::vector<int32_t> cursor(bins->color_start.begin(), bins->color_start.end() - 1);
    for (int c = 0; c < n_cells; ++c) bins->color_cells[cursor[colors[c]]++] = c;
  }
  return -1;
}

// P2G accumulates each cell's particles into a dense window of the 2x2x2 blocks their stencils
// can reach, one 8-float record per node: [mass, momentum xyz, position moment xyz, m D] (the
// position moment sum w m (x_p - x_i) has the same form as the APIC term A (x_i - x_p), so it
// rides in the same multiply-adds). A node update is then three 8-wide multiply-adds; the window
// (16 KB) stays in L1 and is added to the grid fields once per cell. The last lane sums m D
// (damage, csrc/common/mpm_fragments.h) for the fragment partition; it is zero without it. Cells next to a contact
// block also fill a second window of 4-float records with the mass gradient. With AVX-512, cells
// that need mass and momentum only take p2g_cell_window_mass (4-float records, below).
constexpr int kWindow = 2 * kBlock;                        // window nodes per axis
constexpr int kWindowNodes = kWindow * kWindow * kWindow;

namespace {

// The particles of a cell lie wherever the caller put them (together if it ordered them with
// fracture_gs.mpm.ordering.spatial_order, scattered otherwise), so P2G asks for the data of the
// particle kPrefetchAhead places later in the cell while it scatters the current one.
constexpr int kPrefetchAhead = 6;

inline void prefetch_particle(const ParticleArrays& p, int q) {
  __builtin_prefetch(p.x + 3 * q);
  __builtin_prefetch(p.v + 3 * q);
  __builtin_prefetch(p.C + 9 * q);
  __builtin_prefetch(p.C + 9 * q + 8);
  __builtin_prefetch(p.stress + 9 * q);
  __builtin_prefetch(p.stress + 9 * q + 8);
  __builtin_prefetch(p.mass + q);
  __builtin_prefetch(p.rest_volume + q);
}

// True if a stencil whose first node lies at l relative to a cell's block origin starts in that
// block: then it stays inside the cell's window (P2G) or span (fragments), and reaches only the
// blocks the binning marked touched.
inline bool starts_in_block(int lx, int ly, int lz) {
  return ((unsigned)lx < (unsigned)kBlock) & ((unsigned)ly < (unsigned)kBlock) & ((unsigned)lz < (unsigned)kBlock);
}

// Runs scatter(q, aw, lx, ly, lz, m, A) for each particle q of a cell whose stencil starts in the
// cell's block (aw: its stencil weights; l: its first stencil node relative to `origin`; m its mass,
// A its APIC affine matrix). Returns the smallest index of a particle of the cell whose stencil does
// not start there (skipped), or -1.
template <class Scatter>
long long for_cell_particles(const BinsView& bins, int cell, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                             const int origin[3], const Scatter& scatter) {
  const int end = bins.cell_start[cell + 1];
  long long misplaced = -1;
  for (int it = bins.cell_start[cell]; it < end; ++it) {
    const int q = bins.order[it];
    if (it + kPrefetchAhead < end) prefetch_particle(p, bins.order[it + kPrefetchAhead]);
    AxisWeights aw[3];
    stencil_weights(p.x + 3 * q, geo, aw);
    const int lx = aw[0].base - origin[0], ly = aw[1].base - origin[1], lz = aw[2].base - origin[2];
    if (!starts_in_block(lx, ly, lz)) {
      misplaced = misplaced < 0 || q < misplaced ? q : misplaced;
      continue;
    }
    const float m = p.mass[q];
    float A[9];
    apic_affine(p.C + 9 * q, p.stress + 9 * q, m, p.rest_volume[q], dt, geo.inv_dx, A);
    scatter(q, aw, lx, ly, lz, m, A);
  }
  return misplaced;
}

// Scatters the particles of one cell into `window` (zeroed here). origin: node coordinates of
// the window's first node. kWithContact: also the mass gradient into `gradient_window` (zeroed
// here; lanes 0-2), which only the contact pass reads. Returns the smallest index of a particle
// of the cell whose stencil does not start in the cell's block (it is skipped: its nodes lie
// outside the window), or -1.
template <bool kWithContact>
long long p2g_cell_window(const BinsView& bins, int cell, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                          const int origin[3], Record* FGS_RESTRICT window, Lane4* FGS_RESTRICT gradient_window) {
  std::memset(static_cast<void*>(window), 0, sizeof(Record) * kWindowNodes);
  if constexpr (kWithContact) std::memset(static_cast<void*>(gradient_window), 0, sizeof(Lane4) * kWindowNodes);
  const float dx = geo.dx;
  return for_cell_particles(bins, cell, p, geo, dt, origin, [&](int q, const AxisWeights aw[3], int lx, int ly, int lz,
                                                                float m, const float A[9]) {
    const float damage = p.damaged ? m * particle_damage(p.damaged[q]) : 0.f;
    const ParticleRecords records = particle_records(m, p.v + 3 * q, A, damage);  // csrc/mpm/p2g_records.h
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        const ColumnRecords column = column_records(records, aw, a, b, dx);
        const int row_offset = ((lx + a) * kWindow + (ly + b)) * kWindow + lz;
        Record* row = window + row_offset;
        for (int c = 0; c < 3; ++c) row[c] += column.node_record(c);
        if constexpr (kWithContact) {
          Lane4* gradient_row = gradient_window + row_offset;
          for (int c = 0; c < 3; ++c) gradient_row[c] += column.node_gradient(c);
        }
      }
    }
  });
}

// Runs row(block, window_offset, grid_node) for each row of kBlock nodes along z of a cell's
// window: window_offset is the row's first node in the window, grid_node its first node in the
// object's grid (block: the grid block holding the row). Blocks outside the grid are skipped: no
// stencil reaches them, so their records are zero.
template <class Row>
void for_window_rows(const int block_ijk[3], const GridShape& s, const Row& row) {
  for (int di = 0; di < 2; ++di)
    for (int dj = 0; dj < 2; ++dj)
      for (int dk = 0; dk < 2; ++dk) {
        const int bi = block_ijk[0] + di, bj = block_ijk[1] + dj, bk = block_ijk[2] + dk;
        if (bi >= s.bx || bj >= s.by || bk >= s.bz) continue;
        const int block = (bi * s.by + bj) * s.bz + bk;
        const long long first = (long long)block * kBlockNodes;
        for (int li = 0; li < kBlock; ++li)
          for (int lj = 0; lj < kBlock; ++lj)
            row(block, ((di * kBlock + li) * kWindow + dj * kBlock + lj) * kWindow + dk * kBlock,
                first + (li * kBlock + lj) * kBlock);
      }
}

// Adds a cell's window into the grid fields of its object. Position moment and mass gradient go
// only to contact blocks (contact[block] != 0; none if contact is nullptr); gradient_window is read
// only there.
void p2g_flush_window(const Record* FGS_RESTRICT window, const Lane4* FGS_RESTRICT gradient_window,
                      const int block_ijk[3], const GridShape& s, const uint8_t* contact, float* FGS_RESTRICT mass,
                      float* FGS_RESTRICT momentum, float* FGS_RESTRICT gradient, float* FGS_RESTRICT moment,
                      float* FGS_RESTRICT damage) {
  for_window_rows(block_ijk, s, [&](int block, int src_offset, long long dst) {
    const bool with_contact = contact != nullptr && contact[block] != 0;
    const Record* src = window + src_offset;
    for (int lk = 0; lk < kBlock; ++lk) {
      const Record r = src[lk];
      const long long idx = dst + lk;
      mass[idx] += r[0];
      for (int d = 0; d < 3; ++d) momentum[3 * idx + d] += r[1 + d];
      if (damage) damage[idx] += r[7];
      if (with_contact && moment)
        for (int d = 0; d < 3; ++d) moment[3 * idx + d] += r[4 + d];
      if (with_contact && gradient) {
        const Lane4 g = gradient_window[src_offset + lk];
        for (int d = 0; d < 3; ++d) gradient[3 * idx + d] += g[d];
      }
    }
  });
}

#if defined(__AVX512F__)
// P2G of a cell that needs mass and momentum only (no contact block in its window, no fragments):
// 4-float node records [mass, momentum xyz], so that a stencil column's three nodes (12 contiguous
// floats of the window) fit one AVX-512 register and a column costs one multiply and one
// multiply-add where p2g_cell_window spends two per node. The records are the same formula,
// node_record(c) = w_c in_plane + (w_c pz_c) along (csrc/mpm/p2g_records.h). Same return value
// as p2g_cell_window; `window` (kWindowNodes x 4 floats) is zeroed here.
using Vec16 = float __attribute__((vector_size(64)));
constexpr __mmask16 kColumnLanes = 0x0FFF;  // three nodes of 4 floats

// v in lanes 0-3, 4-7 and 8-11 (the three nodes of a column); zero in lanes 12-15.
inline Vec16 three_nodes(Lane4 v) {
  return (Vec16)_mm512_maskz_broadcast_f32x4(kColumnLanes, (__m128)v);
}

// v[c] in the four lanes of node c (c < 3); v[3] in lanes 12-15.
inline Vec16 node_lanes(Lane4 v) {
  const __m512i lanes = _mm512_set_epi32(3, 3, 3, 3, 2, 2, 2, 2, 1, 1, 1, 1, 0, 0, 0, 0);
  return (Vec16)_mm512_permutexvar_ps(lanes, _mm512_castps128_ps512((__m128)v));
}

long long p2g_cell_window_mass(const BinsView& bins, int cell, const ParticleArrays& p, const MPMGeometry& geo,
                               float dt, const int origin[3], float* FGS_RESTRICT window) {
  std::memset(static_cast<void*>(window), 0, sizeof(float) * 4 * kWindowNodes);
  const float dx = geo.dx;
  return for_cell_particles(bins, cell, p, geo, dt, origin, [&](int q, const AxisWeights aw[3], int lx, int ly, int lz,
                                                                float m, const float A[9]) {
    const float* v = p.v + 3 * q;
    // The particle's record directions (particle_records, mass and momentum lanes) in each of the
    // column's three nodes; lanes 12-15 are zero.
    const Lane4 base4 = {m, m * v[0], m * v[1], m * v[2]};
    const Lane4 affine_x4 = {0.f, A[0], A[3], A[6]}, affine_y4 = {0.f, A[1], A[4], A[7]};
    const Lane4 affine_z4 = {0.f, A[2], A[5], A[8]};
    const Vec16 base = three_nodes(base4), affine_x = three_nodes(affine_x4);
    const Vec16 affine_y = three_nodes(affine_y4), affine_z = three_nodes(affine_z4);
    Lane4 wz = {0.f, 0.f, 0.f, 0.f}, wz_pz = wz;
    for (int c = 0; c < 3; ++c) {
      wz[c] = aw[2].w[c];
      wz_pz[c] = aw[2].w[c] * (((float)c - aw[2].f) * dx);
    }
    const Vec16 node_w = node_lanes(wz), node_w_pz = node_lanes(wz_pz);
    for (int a = 0; a < 3; ++a) {
      const float px = ((float)a - aw[0].f) * dx;
      for (int b = 0; b < 3; ++b) {
        const float py = ((float)b - aw[1].f) * dx;
        const float wab = aw[0].w[a] * aw[1].w[b];
        const Vec16 in_plane = wab * base + (wab * px) * affine_x + (wab * py) * affine_y;
        const Vec16 along = wab * affine_z;
        const Vec16 records = node_w * in_plane + node_w_pz * along;
        float* row = window + 4 * (((lx + a) * kWindow + (ly + b)) * kWindow + lz);
        const __m512 sum = _mm512_add_ps(_mm512_maskz_loadu_ps(kColumnLanes, row), (__m512)records);
        _mm512_mask_storeu_ps(row, kColumnLanes, sum);
      }
    }
  });
}

// Adds a window of p2g_cell_window_mass into the grid's mass and momentum (as p2g_flush_window).
void p2g_flush_window_mass(const float* FGS_RESTRICT window, const int block_ijk[3], const GridShape& s,
                           float* FGS_RESTRICT mass, float* FGS_RESTRICT momentum) {
  for_window_rows(block_ijk, s, [&](int, int src_offset, long long dst) {
    const float* src = window + 4 * src_offset;
    for (int lk = 0; lk < kBlock; ++lk) {
      mass[dst + lk] += src[4 * lk];
      for (int d = 0; d < 3; ++d) momentum[3 * (dst + lk) + d] += src[4 * lk + 1 + d];
    }
  });
}
#endif

// Marks (flags[block] = 1) every block that may hold a split node in this substep, from the damage
// flags of the particles: a node's damage D_i is nonzero only in the window (blocks c .. c + 1 per
// axis) of a cell c holding a damaged particle; a particle's damage gradient only if its stencil
// reaches such a node, so its cell lies within c - 1 .. c + 1; and its reference key can split only
// the nodes of its stencil, in blocks c - 1 .. c + 2 (csrc/common/mpm_fragments.h). Blocks outside
// this reach never split, and need the contact fields only where they are contact blocks. Marked
// for every grid alike (a superset).
void mark_split_reach(const BinsView& bins, const uint8_t* damaged, const GridShape& s, uint8_t* flags) {
  const int n_blocks = s.blocks();
  std::vector<uint8_t> damaged_cell(bins.n_cells);
#pragma omp parallel for schedule(static)
  for (int cell = 0; cell < bins.n_cells; ++cell) {
    uint8_t any = 0;
    for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) any |= damaged[bins.order[it]];
    damaged_cell[cell] = any;
  }
  for (int cell = 0; cell < bins.n_cells; ++cell) {
    if (!damaged_cell[cell]) continue;
    int c[3];
    block_coords(bins.cell_key[cell] % n_blocks, s, c);
    for (int bi = std::max(c[0] - 1, 0); bi <= std::min(c[0] + 2, s.bx - 1); ++bi)
      for (int bj = std::max(c[1] - 1, 0); bj <= std::min(c[1] + 2, s.by - 1); ++bj)
        for (int bk = std::max(c[2] - 1, 0); bk <= std::min(c[2] + 2, s.bz - 1); ++bk)
          flags[(bi * s.by + bj) * s.bz + bk] = 1;
  }
}

}  // namespace

BoundReport p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                    GridArrays grid) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_touched = bins.n_touched;
  const int n_blocks = s.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    long long first = (long long)(bins.touched[t] / n_blocks) * nodes +
                      (long long)(bins.touched[t] % n_blocks) * kBlockNodes;
    std::memset(grid.mass + first, 0, sizeof(float) * kBlockNodes);
    std::memset(grid.momentum + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    if (grid.mass_gradient) std::memset(grid.mass_gradient + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    if (grid.position_moment) std::memset(grid.position_moment + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    if (grid.damage) std::memset(grid.damage + first, 0, sizeof(float) * kBlockNodes);
    if (grid.reference) std::memset(grid.reference + first, 0, sizeof(int64_t) * kBlockNodes);
  }
  // Contact blocks (block ids touched by two grids): only there does P2G add the position moment
  // and the mass gradient, the contact pass's inputs; a cell computes the gradient only if its
  // window (2x2x2 blocks) contains one. With fragments the two sides of a split node meet through
  // the contact pass too, so the blocks that may hold a split node this substep get them as well
  // (mark_split_reach).
  std::vector<uint8_t> contact_flag;
  const bool fragments = p.damaged != nullptr && grid.mass_gradient && grid.position_moment;
  if (fragments || ((grid.mass_gradient || grid.position_moment) && bins.n_contact > 0)) {
    contact_flag.assign(n_blocks, 0);
    for (int i = 0; i < bins.n_contact; ++i) contact_flag[bins.contact_blocks[i]] = 1;
    if (fragments) mark_split_reach(bins, p.damaged, s, contact_flag.data());
  }
  const uint8_t* contact = contact_flag.empty() ? nullptr : contact_flag.data();
  long long misplaced = std::numeric_limits<long long>::max();
#pragma omp parallel reduction(min : misplaced)
  {
    std::vector<Record> window(kWindowNodes);  // per thread
    std::vector<Lane4> gradient_window(contact ? kWindowNodes : 0);
#if defined(__AVX512F__)
    // Cells with no contact fields in their window take the 4-float records (with fragments such
    // a cell has no damaged particle, mark_split_reach: its damage lane would be zero).
    std::vector<float> window_mass(4 * kWindowNodes);
#endif
    for (int color = 0; color < 8; ++color) {
      const int c_begin = bins.color_start[color], c_end = bins.color_start[color + 1];
#pragma omp for schedule(dynamic, 2)
      for (int ci = c_begin; ci < c_end; ++ci) {
        const int cell = bins.color_cells[ci];
        const int grid_index = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
        int block_ijk[3];
        block_coords(block, s, block_ijk);
        const int origin[3] = {block_ijk[0] * kBlock, block_ijk[1] * kBlock, block_ijk[2] * kBlock};
        bool near_contact = false;
        if (contact)
          for (int di = 0; di < 2; ++di)
            for (int dj = 0; dj < 2; ++dj)
              for (int dk = 0; dk < 2; ++dk) {
                const int bi = block_ijk[0] + di, bj = block_ijk[1] + dj, bk = block_ijk[2] + dk;
                if (bi < s.bx && bj < s.by && bk < s.bz) near_contact |= contact[(bi * s.by + bj) * s.bz + bk] != 0;
              }
        const long long grid_offset = (long long)grid_index * nodes;
#if defined(__AVX512F__)
        if (!near_contact) {
          const long long stray = p2g_cell_window_mass(bins, cell, p, geo, dt, origin, window_mass.data());
          if (stray >= 0 && stray < misplaced) misplaced = stray;
          p2g_flush_window_mass(window_mass.data(), block_ijk, s, grid.mass + grid_offset,
                                grid.momentum + 3 * grid_offset);
          continue;
        }
#endif
        const long long stray =
            near_contact ? p2g_cell_window<true>(bins, cell, p, geo, dt, origin, window.data(), gradient_window.data())
                         : p2g_cell_window<false>(bins, cell, p, geo, dt, origin, window.data(), nullptr);
        if (stray >= 0 && stray < misplaced) misplaced = stray;
        p2g_flush_window(window.data(), gradient_window.data(), block_ijk, s, near_contact ? contact : nullptr,
                         grid.mass + grid_offset, grid.momentum + 3 * grid_offset,
                         grid.mass_gradient ? grid.mass_gradient + 3 * grid_offset : nullptr,
                         grid.position_moment ? grid.position_moment + 3 * grid_offset : nullptr,
                         grid.damage ? grid.damage + grid_offset : nullptr);
      }
    }
  }
  BoundReport report;
  if (misplaced != std::numeric_limits<long long>::max()) report.misplaced = misplaced;
  return report;
}

void grid_update_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo, float dt,
                     const float* gravity, float mass_eps, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    const long long first = (long long)(touched[t] / n_blocks) * nodes + (long long)(touched[t] % n_blocks) * kBlockNodes;
    for (long long idx = first; idx < first + kBlockNodes; ++idx) {
      grid_node_velocity(grid.mass[idx], grid.momentum + 3 * idx, dt, gravity, mass_eps, grid.velocity + 3 * idx);
    }
  }
}

void boundaries_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo,
                    const BoundaryParams& bc, float mass_eps, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    const int block = touched[t] % n_blocks;
    const long long first = (long long)(touched[t] / n_blocks) * nodes + (long long)block * kBlockNodes;
    for (int local = 0; local < kBlockNodes; ++local) {
      const long long idx = first + local;
      if (!(grid.mass[idx] > mass_eps)) continue;
      int ijk[3];
      node_coords(block * kBlockNodes + local, geo.shape, ijk);
      apply_boundary(ijk, bc, grid.velocity + 3 * idx);
    }
  }
}

void collision_cpu(const int32_t* contact_blocks, int n_contact, const MPMGeometry& geo, const ContactParams& params,
                   GridArrays grid) {
  const long long nodes = geo.shape.nodes();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_contact; ++t) {
    const long long first = (long long)contact_blocks[t] * kBlockNodes;
    for (long long node = first; node < first + kBlockNodes; ++node)
      contact_node(node, nodes, geo.n_grids, grid.mass, grid.velocity, grid.mass_gradient, grid.position_moment,
                   params);
  }
}

namespace {

// True if all nine entries are finite (x * 0 is NaN exactly for a non-finite x; summed as a tree).
inline bool finite_sum9(const float a[9]) {
  const float s = ((a[0] * 0.f + a[1] * 0.f) + (a[2] * 0.f + a[3] * 0.f)) +
                  ((a[4] * 0.f + a[5] * 0.f) + (a[6] * 0.f + a[7] * 0.f)) + a[8] * 0.f;
  return s == 0.f;
}

// Velocity of a node of particle q's own object grid (no fragments, or side A everywhere).
struct ObjectNodeVelocity {
  const float* velocity;  // the object's grid
  const float* operator()(long long node, uint32_t) const { return velocity + 3 * node; }
};

// Velocity of a node for a particle with fragments, from the side mask of the partition: field B
// (the grid K later) at the stencil nodes whose bit is set, the object's grid elsewhere.
struct MaskedNodeVelocity {
  const float* velocity;  // the object's grid (field A)
  long long field_b;      // floats from a node of field A to the same node of field B
  uint32_t mask;
  const float* operator()(long long node, uint32_t bit) const {
    return velocity + 3 * node + ((mask & bit) ? field_b : 0);
  }
};

// Velocity of a node for a particle with fragments, without a side mask: the side from the
// reference key of the node (FragmentNodeVelocity, csrc/common/mpm_fragments.h).
struct ReferenceNodeVelocity {
  FragmentNodeVelocity by_reference;
  const float* operator()(long long node, uint32_t) const { return by_reference(node); }
};

// g2p_gather (csrc/common/mpm_transfer.h) with the node velocities as 4-wide vectors: per node
// two vector multiply-adds (sums along z), per (x, y) column four, instead of twelve scalar
// ones per node. node_velocity(node index within one grid, side_bit of the stencil node) gives
// the 3 floats to read: the object's grid, or with fragments the field (A or B) of q's side.
// Same outputs as the scalar gathers; tested against the same torch twin.
template <class NodeVelocity>
bool g2p_gather_cpu(long long q, const G2PInputs& in, const MPMGeometry& geo, float dt,
                    const NodeVelocity& node_velocity, const G2POutputs& out, float F_trial[9]) {
  const GridShape& s = geo.shape;
  const float dx = geo.dx;
  AxisWeights aw[3];
  stencil_weights(in.x + 3 * q, geo, aw);
  int oz[3];
  float wz_pz[3];
  for (int c = 0; c < 3; ++c) {
    oz[c] = offset_z(aw[2].base + c, s);
    wz_pz[c] = aw[2].w[c] * ((float)c - aw[2].f) * dx;
  }
  Lane4 vp = {0.f, 0.f, 0.f, 0.f}, bx = vp, by = vp, bz = vp;  // B column k = sum w v (x_i - x_p)_k
  for (int a = 0; a < 3; ++a) {
    const int ox = offset_x(aw[0].base + a, s);
    const float px = ((float)a - aw[0].f) * dx;
    for (int b = 0; b < 3; ++b) {
      const int oxy = ox + offset_y(aw[1].base + b, s);
      const float py = ((float)b - aw[1].f) * dx;
      Lane4 column = {0.f, 0.f, 0.f, 0.f}, column_z = column;
      for (int c = 0; c < 3; ++c) {
        Lane4 v;  // lanes 0-2: the node velocity (lane 3 reads the next node's x and is unused;
                  // stencils never reach a grid's last node, so the read stays in bounds)
        __builtin_memcpy(&v, node_velocity((long long)(oxy + oz[c]), side_bit(a, b, c)), sizeof(v));
        column += aw[2].w[c] * v;
        column_z += wz_pz[c] * v;
      }
      const float wab = aw[0].w[a] * aw[1].w[b];
      vp += wab * column;
      bx += (wab * px) * column;
      by += (wab * py) * column;
      bz += wab * column_z;
    }
  }
  const float apic_scale = 4.f * geo.inv_dx * geo.inv_dx;
  float C[9];
  for (int d = 0; d < 3; ++d) {
    C[3 * d] = apic_scale * bx[d];
    C[3 * d + 1] = apic_scale * by[d];
    C[3 * d + 2] = apic_scale * bz[d];
  }
  const float velocity_p[3] = {vp[0], vp[1], vp[2]};
  return g2p_advect(q, in, dt, velocity_p, C, out, F_trial);
}

}  // namespace

namespace {

// Particles that share a stencil base read the same 27 node velocities: G2P gathers up to
// kGroupLanes such particles, consecutive in memory (spatial_order puts a cell's particles
// together), at once, one per lane of an 8-wide vector. Every node velocity is then one broadcast
// for the whole group instead of one load per particle, and each multiply-add of
// g2p_gather_cpu serves 8 particles; the weights, the advection and F_trial run on the lanes too.
// Runs shorter than kMinGroup go one by one.
constexpr int kGroupLanes = 8;
constexpr int kMinGroup = 3;
using Vec8 = float __attribute__((vector_size(32)));
using Vec8i = int32_t __attribute__((vector_size(32)));

struct GatherGroup {
  long long first;  // the particles first .. first + count - 1
  int count = 0;
  int base[3];      // their common stencil base
  int32_t side_masks[kGroupLanes];  // each particle's side mask (fragments; 0: side A everywhere)
  uint32_t any_side_b = 0;          // the masks OR-ed
};

// v rounded to float before anything else uses it (product_rn for 8 lanes).
inline Vec8 rounded8(Vec8 v) {
#if defined(__AVX512F__)
  asm("" : "+v"(v));
#else
  asm("" : "+x"(v));
#endif
  return v;
}

// g2p_gather_cpu and g2p_advect for the particles of `group` (all on the grid `velocity`), lane l
// for particle group.first + l: writes x, v and C of `out` and F_trial[i][l]; returns how many
// positions were clamped. The weights are axis_weights' operations on 8 lanes (the squares rounded
// before anything uses them): the particles weigh the nodes as P2G does. With fragments, a lane
// whose side mask has a stencil node's bit reads that node's field B (field_b floats later), as
// MaskedNodeVelocity: both fields' values are broadcast and each lane selects its own.
int g2p_group(const GatherGroup& group, const G2PInputs& in, const MPMGeometry& geo, float dt, const float* velocity,
              long long field_b, const G2POutputs& out, float F_trial[9][kGroupLanes]) {
  const GridShape& s = geo.shape;
  const float dx = geo.dx;
  const int count = group.count;
  const long long q0 = group.first;
  Vec8 xp[3], w[3][3], f[3];
  for (int d = 0; d < 3; ++d) {
    float lanes[kGroupLanes];
    for (int l = 0; l < kGroupLanes; ++l) lanes[l] = in.x[3 * (q0 + (l < count ? l : 0)) + d];
    __builtin_memcpy(&xp[d], lanes, sizeof(Vec8));
    const Vec8 X = rounded8((xp[d] - geo.lower[d]) * geo.inv_dx);  // grid_coordinate
    f[d] = X - (float)group.base[d];
    w[d][0] = 0.5f * rounded8((1.5f - f[d]) * (1.5f - f[d]));
    w[d][1] = 0.75f - rounded8((f[d] - 1.f) * (f[d] - 1.f));
    w[d][2] = 0.5f * rounded8((f[d] - 0.5f) * (f[d] - 0.5f));
  }
  int oz[3];
  Vec8 wz_pz[3];
  for (int c = 0; c < 3; ++c) {
    oz[c] = offset_z(group.base[2] + c, s);
    wz_pz[c] = w[2][c] * (((float)c - f[2]) * dx);
  }
  Vec8i side_masks;
  __builtin_memcpy(&side_masks, group.side_masks, sizeof(Vec8i));
  Vec8 vp[3] = {}, bx[3] = {}, by[3] = {}, bz[3] = {};  // B column k = sum w v (x_i - x_p)_k
  for (int a = 0; a < 3; ++a) {
    const int ox = offset_x(group.base[0] + a, s);
    const Vec8 px = ((float)a - f[0]) * dx;
    for (int b = 0; b < 3; ++b) {
      const int oxy = ox + offset_y(group.base[1] + b, s);
      const Vec8 py = ((float)b - f[1]) * dx;
      Vec8 column[3] = {}, column_z[3] = {};
      for (int c = 0; c < 3; ++c) {
        const float* v = velocity + 3 * (long long)(oxy + oz[c]);
        const uint32_t bit = side_bit(a, b, c);
        if (group.any_side_b & bit) {  // some lane reads field B here
          const Vec8i on_side_b = (side_masks & (int32_t)bit) != 0;
          for (int d = 0; d < 3; ++d) {
            const Vec8 node = on_side_b ? Vec8{} + v[d + field_b] : Vec8{} + v[d];
            column[d] += w[2][c] * node;
            column_z[d] += wz_pz[c] * node;
          }
          continue;
        }
        for (int d = 0; d < 3; ++d) {
          column[d] += w[2][c] * v[d];
          column_z[d] += wz_pz[c] * v[d];
        }
      }
      const Vec8 wab = w[0][a] * w[1][b];
      const Vec8 wab_px = wab * px, wab_py = wab * py;
      for (int d = 0; d < 3; ++d) {
        vp[d] += wab * column[d];
        bx[d] += wab_px * column[d];
        by[d] += wab_py * column[d];
        bz[d] += wab * column_z[d];
      }
    }
  }
  const float apic_scale = 4.f * geo.inv_dx * geo.inv_dx;
  Vec8 C[9];
  for (int d = 0; d < 3; ++d) {
    C[3 * d] = apic_scale * bx[d];
    C[3 * d + 1] = apic_scale * by[d];
    C[3 * d + 2] = apic_scale * bz[d];
  }
  // g2p_advect on the lanes: the position (clamped into the domain), then F_trial = (I + dt C) F_E.
  float x_new[3][kGroupLanes], v_new[3][kGroupLanes], C_new[9][kGroupLanes];
  int clamped_lanes = 0;
  for (int d = 0; d < 3; ++d) {
    const Vec8 moved = xp[d] + dt * vp[d];
    const auto below = moved < in.clamp_lower[d], above = moved > in.clamp_upper[d];
    const Vec8 lower = Vec8{} + in.clamp_lower[d], upper = Vec8{} + in.clamp_upper[d];
    const Vec8 kept = below ? lower : (above ? upper : moved);
    __builtin_memcpy(x_new[d], &kept, sizeof(Vec8));
    __builtin_memcpy(v_new[d], &vp[d], sizeof(Vec8));
    for (int l = 0; l < count; ++l) clamped_lanes |= (below[l] | above[l]) ? 1 << l : 0;
  }
  for (int i = 0; i < 9; ++i) __builtin_memcpy(C_new[i], &C[i], sizeof(Vec8));
  Vec8 F_E[9];
  for (int i = 0; i < 9; ++i) {
    float lanes[kGroupLanes];
    for (int l = 0; l < kGroupLanes; ++l) lanes[l] = in.F_E[9 * (q0 + (l < count ? l : 0)) + i];
    __builtin_memcpy(&F_E[i], lanes, sizeof(Vec8));
  }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const Vec8 product = (dt * C[3 * r]) * F_E[c] + (dt * C[3 * r + 1]) * F_E[3 + c] +
                           (dt * C[3 * r + 2]) * F_E[6 + c] + F_E[3 * r + c];
      __builtin_memcpy(F_trial[3 * r + c], &product, sizeof(Vec8));
    }
  for (int l = 0; l < count; ++l) {
    const long long q = q0 + l;
    for (int d = 0; d < 3; ++d) {
      out.x[3 * q + d] = x_new[d][l];
      out.v[3 * q + d] = v_new[d][l];
    }
    for (int i = 0; i < 9; ++i) out.C[9 * q + i] = C_new[i][l];
  }
  return __builtin_popcount(clamped_lanes);
}

}  // namespace

G2PStats g2p_cpu(long long n, const G2PInputs& in, const MPMGeometry& geo, float dt,
                 const float* grid_velocity, G2POutputs out, const FragmentView* frag) {
  long long clamped = 0, first_bad = n;
  float max_speed_sq = 0.f;
  const long long nodes = geo.shape.nodes();
  constexpr long long kChunk = 512;
  const long long n_chunks = (n + kChunk - 1) / kChunk;
#pragma omp parallel reduction(+ : clamped) reduction(min : first_bad) reduction(max : max_speed_sq)
  {
    // Gather each particle, hand F_trial to the thread's constitutive stream, store what it returns.
    ConstitutiveStream stream;
    auto store = [&](long long q, const float F_E[9], const float* state, const float tau[9], float dissipated) {
      g2p_store_material(q, in, out, F_E, state, tau, dissipated);
      if (!finite_sum9(F_E)) first_bad = q < first_bad ? q : first_bad;
    };
    // After particle q's gather (x, v, C written, F_trial computed): health, then the material.
    auto finish_particle = [&](long long q, bool was_clamped, const float F_trial[9]) {
      clamped += was_clamped ? 1 : 0;
      const float* xq = out.x + 3 * q;
      const float* vq = out.v + 3 * q;
      // x * 0 is NaN exactly when x is not finite; a tree of sums keeps the chain short.
      const float probe = ((xq[0] * 0.f + xq[1] * 0.f) + (xq[2] * 0.f + vq[0] * 0.f)) + (vq[1] * 0.f + vq[2] * 0.f);
      if (probe == 0.f) {
        const float speed_sq = vq[0] * vq[0] + vq[1] * vq[1] + vq[2] * vq[2];
        max_speed_sq = speed_sq > max_speed_sq ? speed_sq : max_speed_sq;
      } else {
        first_bad = q < first_bad ? q : first_bad;
      }
      stream.push(q, F_trial, in.state + (long long)in.state_stride * q, in.state_stride, g2p_material_row(q, in),
                  store);
    };
    const long long field_b = frag != nullptr ? 3 * frag->n_fields * nodes : 0;  // floats from field A to B
    // One particle on its own (every kind of fragment reading).
    auto gather_one = [&](long long q) {
      float F_trial[9];
      const bool split = frag != nullptr && frag->split_particle[q] != 0;
      const float* own_grid = grid_velocity + 3 * (long long)in.grid_id[q] * nodes;
      const uint32_t mask = split && frag->side_mask != nullptr ? (uint32_t)frag->side_mask[q] : 0u;
      bool was_clamped;
      if (split && frag->side_mask == nullptr)
        was_clamped = g2p_gather_cpu(
            q, in, geo, dt, ReferenceNodeVelocity{{grid_velocity, frag, in.grid_id[q], q, nodes}}, out, F_trial);
      else if (mask != 0)  // side B somewhere in the stencil
        was_clamped = g2p_gather_cpu(q, in, geo, dt, MaskedNodeVelocity{own_grid, field_b, mask},
                                     out, F_trial);
      else  // no fragments, or side A at every split node it reaches: the object's own grid
        was_clamped = g2p_gather_cpu(q, in, geo, dt, ObjectNodeVelocity{own_grid}, out, F_trial);
      finish_particle(q, was_clamped, F_trial);
    };
    GatherGroup group;
    auto flush_group = [&]() {
      if (group.count >= kMinGroup) {
        float F_trial[9][kGroupLanes];
        const float* own_grid = grid_velocity + 3 * (long long)in.grid_id[group.first] * nodes;
        clamped += g2p_group(group, in, geo, dt, own_grid, field_b, out, F_trial);
        for (int l = 0; l < group.count; ++l) {
          float F_lane[9];
          for (int i = 0; i < 9; ++i) F_lane[i] = F_trial[i][l];
          finish_particle(group.first + l, false, F_lane);
        }
      } else {
        for (int l = 0; l < group.count; ++l) gather_one(group.first + l);
      }
      group.count = 0;
      group.any_side_b = 0;
    };
    // Dynamic chunks of kChunk particles: the constitutive cost varies between particles
    // (eigen-path lanes). Groups never cross a chunk, and a particle's result depends only on its
    // own inputs and on the run of particles around it in memory, so the schedule and the number
    // of threads cannot change any bit.
#pragma omp for schedule(dynamic, 1) nowait
    for (long long chunk = 0; chunk < n_chunks; ++chunk) {
      const long long end = std::min(n, (chunk + 1) * kChunk);
      for (long long q = chunk * kChunk; q < end; ++q) {
        // A particle joins the group if it has the group's grid and stencil base and its sides
        // are known from a side mask (or it reaches no split node).
        const bool split = frag != nullptr && frag->split_particle[q] != 0;
        if (split && frag->side_mask == nullptr) {
          flush_group();
          gather_one(q);
          continue;
        }
        const int32_t side_mask = split ? frag->side_mask[q] : 0;
        int base[3];
        stencil_base(in.x + 3 * q, geo, base);
        const bool joins = group.count > 0 && group.count < kGroupLanes && in.grid_id[q] == in.grid_id[group.first] &&
                           base[0] == group.base[0] && base[1] == group.base[1] && base[2] == group.base[2];
        if (!joins) {
          flush_group();
          group.first = q;
          for (int d = 0; d < 3; ++d) group.base[d] = base[d];
          for (int l = 0; l < kGroupLanes; ++l) group.side_masks[l] = 0;
        }
        group.side_masks[group.count++] = side_mask;
        group.any_side_b |= (uint32_t)side_mask;
      }
      flush_group();
    }
    stream.finish(store);
  }
  return G2PStats{clamped, first_bad < n ? first_bad : -1, sqrtf(max_speed_sq)};
}

}  // namespace fgs
