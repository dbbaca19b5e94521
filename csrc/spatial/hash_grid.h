// Uniform hash grid for fixed-radius neighbour queries, shared by the CPU and CUDA kernels.
//
// Space is cut into cubic cells of edge `cell` (>= the query radius, so a query looks at the 27
// cells around it). A cell (i, j, k) goes to bucket (i·stride_i + j·stride_j + k) mod
// table_size, its row-major index in the points' bounding box taken modulo a power of two: cells
// next to each other along z are next to each other in memory, so a query reads 9 runs of 3
// consecutive buckets, and a sparse set spread over a large box still needs only ~2 buckets
// per point. Points are sorted by bucket, ties by index (stable), and bucket_start[b] ..
// bucket_start[b + 1] lists bucket b's points. Different cells can share a bucket (wrap-around):
// a query checks every candidate's packed cell against the cell it looks at, so each point is
// met at most once and the results do not depend on collisions.
#pragma once
#include <cmath>
#include <cstdint>

#include "common/hd.h"

namespace fgs {
namespace spatial {

struct HashGrid {
  float origin[3];
  float inv_cell;
  uint32_t table_mask;            // table_size - 1
  int64_t stride_i, stride_j;     // row-major strides of the bounding box's cells
  const int32_t* sorted_point;    // (P,) point indices in bucket order
  const int32_t* bucket_start;    // (table_size + 1,)
  const float* sorted_xyz;        // (P, 3) the points in bucket order (contiguous reads)
  const int64_t* sorted_cell;     // (P,) packed cell of each sorted point (cell_key)
};

// Cell coordinates are offset by kCellBias and packed 21 bits each; the binding refuses point
// sets wider than kMaxCells cells, so every point's cell packs exactly. A query cell outside
// that range cannot hold points and is skipped.
constexpr int kCellBias = 1 << 20;
constexpr int kMaxCells = (1 << 20) - 4;

HOST_DEVICE inline void cell_of(const HashGrid& g, const float* p, int c[3]) {
  for (int a = 0; a < 3; ++a) c[a] = static_cast<int>(floorf((p[a] - g.origin[a]) * g.inv_cell));
}

HOST_DEVICE inline bool cell_packable(int i, int j, int k) {
  return i >= -kCellBias && i < kCellBias && j >= -kCellBias && j < kCellBias &&
         k >= -kCellBias && k < kCellBias;
}

HOST_DEVICE inline int64_t cell_key(int i, int j, int k) {
  return ((int64_t)(i + kCellBias) << 42) | ((int64_t)(j + kCellBias) << 21) | (int64_t)(k + kCellBias);
}

HOST_DEVICE inline uint32_t bucket_of(const HashGrid& g, int i, int j, int k) {
  const int64_t linear = (int64_t)i * g.stride_i + (int64_t)j * g.stride_j + k;
  return static_cast<uint32_t>(static_cast<uint64_t>(linear) & g.table_mask);
}

HOST_DEVICE inline float distance2(const float* a, const float* b) {
  const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
  return dx * dx + dy * dy + dz * dz;
}

// Visits the grid points within radius of q among the cells (ci, cj, k_first .. k_last) of one
// row (k_last - k_first <= 2). Their buckets are consecutive, so the row is one contiguous run of
// sorted points (two when it wraps around the table); a candidate belongs to the row iff its
// packed cell lies in [key(ci, cj, k_first), key(ci, cj, k_last)]. Candidates in the cell
// `skip_key` are visited only from sorted slot `skip_below` + 1 on.
template <class Visit>
HOST_DEVICE inline void scan_row(const HashGrid& g, const float* q, float radius2, int ci, int cj,
                                 int k_first, int k_last, int64_t skip_key, int64_t skip_below,
                                 Visit& visit) {
  if (!cell_packable(ci, cj, k_first) || !cell_packable(ci, cj, k_last)) return;
  const int64_t key_lo = cell_key(ci, cj, k_first), key_hi = key_lo + (k_last - k_first);
  const uint32_t first = bucket_of(g, ci, cj, k_first);
  const uint32_t last = (first + (uint32_t)(k_last - k_first)) & g.table_mask;
  // one run [first, last] or, wrapped, [first, table) and [0, last]
  const int32_t runs[2][2] = {
      {g.bucket_start[first], g.bucket_start[last >= first ? last + 1 : g.table_mask + 1]},
      {g.bucket_start[0], last >= first ? g.bucket_start[0] : g.bucket_start[last + 1]}};
  for (int r = 0; r < 2; ++r)
    for (int32_t s = runs[r][0]; s < runs[r][1]; ++s) {
      const int64_t key = g.sorted_cell[s];
      if (key < key_lo || key > key_hi) continue;  // another cell sharing these buckets
      if (key == skip_key && s <= skip_below) continue;
      const float d2 = distance2(g.sorted_xyz + 3 * (int64_t)s, q);
      if (d2 <= radius2) visit(g.sorted_point[s], d2);
    }
}

// Calls visit(j, d2) for every grid point j with |x_j - q|^2 <= radius2 (radius <= cell): the
// 27 cells around q as 9 rows (ci + di, cj + dj, ck - 1 .. ck + 1).
template <class Visit>
HOST_DEVICE inline void for_each_within(const HashGrid& g, const float* q, float radius2,
                                        Visit& visit) {
  int c[3];
  cell_of(g, q, c);
  for (int di = -1; di <= 1; ++di)
    for (int dj = -1; dj <= 1; ++dj)
      scan_row(g, q, radius2, c[0] + di, c[1] + dj, c[2] - 1, c[2] + 1, -1, -1, visit);
}

// Every pair of grid points within radius exactly once: called for each sorted slot s, it visits
// the partners of point s in the forward half of its neighbourhood — later slots of its own
// cell, the next cell along k, the row (ci, cj + 1, *) and the three rows (ci + 1, *, *).
template <class Visit>
HOST_DEVICE inline void for_each_forward_pair(const HashGrid& g, int64_t s, float radius2,
                                              Visit& visit) {
  const float* q = g.sorted_xyz + 3 * s;
  int c[3];
  cell_of(g, q, c);
  scan_row(g, q, radius2, c[0], c[1], c[2], c[2] + 1, g.sorted_cell[s], s, visit);
  scan_row(g, q, radius2, c[0], c[1] + 1, c[2] - 1, c[2] + 1, -1, -1, visit);
  for (int dj = -1; dj <= 1; ++dj)
    scan_row(g, q, radius2, c[0] + 1, c[1] + dj, c[2] - 1, c[2] + 1, -1, -1, visit);
}

// Keeps the k nearest (by d2, then index) of the points it is shown; k <= kMaxNeighbours.
constexpr int kMaxNeighbours = 16;

struct NearestK {
  int k = 0;
  int count = 0;
  int32_t index[kMaxNeighbours];
  float d2[kMaxNeighbours];

  HOST_DEVICE void offer(int32_t j, float dist2) {
    if (count == k && !(dist2 < d2[k - 1] || (dist2 == d2[k - 1] && j < index[k - 1]))) return;
    int pos = count < k ? count++ : k - 1;
    while (pos > 0 && (dist2 < d2[pos - 1] || (dist2 == d2[pos - 1] && j < index[pos - 1]))) {
      d2[pos] = d2[pos - 1];
      index[pos] = index[pos - 1];
      --pos;
    }
    d2[pos] = dist2;
    index[pos] = j;
  }
};

// Query filter of the k-nearest search: same group, not the query itself.
struct KnnVisit {
  NearestK* best;
  const int32_t* point_group;  // may be null
  int32_t group;
  int32_t self;                // index of the query among the points, or -1
  HOST_DEVICE void operator()(int32_t j, float d2) {
    if (j == self) return;
    if (point_group != nullptr && point_group[j] != group) return;
    best->offer(j, d2);
  }
};

// Union-find with roots that only ever point to smaller indices: every component ends with its
// smallest index as root, whatever order the unions run in (deterministic labels).
// The loads / CAS are supplied by the caller (std::atomic_ref on the CPU, atomicCAS on CUDA).
template <class Ops>
HOST_DEVICE inline int32_t uf_find(int32_t* parent, int32_t x, Ops& ops) {
  int32_t p = ops.load(parent + x);
  while (p != x) {  // path halving: point x at its grandparent (only ever moves toward the root)
    const int32_t gp = ops.load(parent + p);
    if (gp != p) ops.cas(parent + x, p, gp);
    x = p;
    p = ops.load(parent + x);
  }
  return x;
}

template <class Ops>
HOST_DEVICE inline void uf_unite(int32_t* parent, int32_t a, int32_t b, Ops& ops) {
  while (true) {
    a = uf_find(parent, a, ops);
    b = uf_find(parent, b, ops);
    if (a == b) return;
    if (a < b) { const int32_t t = a; a = b; b = t; }  // link the larger root under the smaller
    if (ops.cas(parent + a, a, b)) return;
  }
}

template <class Ops>
struct UniteVisit {
  int32_t* parent;
  const int32_t* group;  // may be null
  int32_t self;
  Ops* ops;
  HOST_DEVICE void operator()(int32_t j, float) {
    if (group != nullptr && group[j] != group[self]) return;
    uf_unite(parent, self, j, *ops);
  }
};

}  // namespace spatial
}  // namespace fgs
