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
#include <type_traits>

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

// Rest-neighbour tables: row i lists up to k points (int32 indices, -1 padding) that were
// point i's neighbours in some earlier configuration (FPGO: the rest state). The number of them
// still within radius of point i now (|x_i - x_j|^2 <= radius2, the distance2 of the grid
// queries) is a lower bound of i's neighbour count, and the share of them kept measures how
// far the neighbourhood has opened since.
// The count stops once it reaches `stop_at` (pass k or more for the full count). Every entry
// the count reads is checked against the num_points points (-1 or 0 .. num_points - 1): one
// that is not gives kInvalidTableEntry, and is never dereferenced.
constexpr int32_t kInvalidTableEntry = -1;

HOST_DEVICE inline int32_t retained_count(const float* points, int64_t num_points, int64_t i,
                                          const int32_t* row, int k, float radius2,
                                          int32_t stop_at) {
  int32_t kept = 0;
  for (int n = 0; n < k && kept < stop_at; ++n) {
    const int32_t j = row[n];
    if (j < -1 || j >= num_points) return kInvalidTableEntry;
    if (j >= 0 && distance2(points + 3 * (int64_t)i, points + 3 * (int64_t)j) <= radius2) ++kept;
  }
  return kept;
}

// Visits the grid points within radius of q among the cells (ci, cj, k_first .. k_last) of one
// row (k_last - k_first <= 2). Their buckets are consecutive, so the row is one contiguous run of
// sorted points (two when it wraps around the table); a candidate belongs to the row iff its
// packed cell lies in [key(ci, cj, k_first), key(ci, cj, k_last)]. Candidates in the cell
// `skip_key` are visited only from sorted slot `skip_below` + 1 on. A visitor that returns bool
// stops the scan by returning true (scan_row then returns true); a void visitor sees every point.
template <class Visit>
HOST_DEVICE inline bool visit_point(Visit& visit, int32_t j, float d2) {
  if constexpr (std::is_same_v<decltype(visit(j, d2)), bool>) {
    return visit(j, d2);
  } else {
    visit(j, d2);
    return false;
  }
}

template <class Visit>
HOST_DEVICE inline bool scan_row(const HashGrid& g, const float* q, float radius2, int ci, int cj,
                                 int k_first, int k_last, int64_t skip_key, int64_t skip_below,
                                 Visit& visit) {
  if (!cell_packable(ci, cj, k_first) || !cell_packable(ci, cj, k_last)) return false;
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
      if (d2 <= radius2 && visit_point(visit, g.sorted_point[s], d2)) return true;
    }
  return false;
}

// Calls row(c, di, dj) for the 9 rows of cells around q (c = q's cell), own row first, until
// a call returns true.
template <class Row>
HOST_DEVICE inline void for_each_row_around(const HashGrid& g, const float* q, Row& row) {
  constexpr int kOrder[3] = {0, -1, 1};
  int c[3];
  cell_of(g, q, c);
  for (int di : kOrder)
    for (int dj : kOrder)
      if (row(c, di, dj)) return;
}

// Calls visit(j, d2) for every grid point j with |x_j - q|^2 <= radius2 (radius <= cell): the
// 27 cells around q as 9 rows (ci + di, cj + dj, ck - 1 .. ck + 1), the row through q's own
// cell first (it holds the most points within radius); a bool visitor returning true ends the
// search early. Visitors that see every point get results independent of the order.
template <class Visit>
HOST_DEVICE inline void for_each_within(const HashGrid& g, const float* q, float radius2,
                                        Visit& visit) {
  auto row = [&](const int* c, int di, int dj) {
    return scan_row(g, q, radius2, c[0] + di, c[1] + dj, c[2] - 1, c[2] + 1, -1, -1, visit);
  };
  for_each_row_around(g, q, row);
}

// Squared distance from coordinate x to the slab of cell index c + d along one axis (d in -1,
// 0, 1; 0 for the query's own cell), minus a margin for the rounding of cell_of, never < 0.
HOST_DEVICE inline float slab_gap2(const HashGrid& g, int axis, float x, int c, int d) {
  if (d == 0) return 0.f;
  const float cell = 1.f / g.inv_cell;
  const float face = g.origin[axis] + (float)(d < 0 ? c : c + 1) * cell;
  const float gap = fabsf(x - face) - 1e-4f * cell;
  return gap > 0.f ? gap * gap : 0.f;
}

// The search of for_each_within for a visitor that only wants points nearer than its current
// bound (visit.bound2(radius2): the k nearest so far give the k-th distance², radius2 until k are
// found): rows and end cells of rows whose slab lies farther than the bound are not scanned.
// The points skipped could never be accepted, so the result is that of for_each_within.
template <class Visit>
HOST_DEVICE inline void for_each_nearer(const HashGrid& g, const float* q, float radius2,
                                        Visit& visit) {
  auto row = [&](const int* c, int di, int dj) {
    const float row2 = slab_gap2(g, 0, q[0], c[0], di) + slab_gap2(g, 1, q[1], c[1], dj);
    const float bound = visit.bound2(radius2);
    if (row2 > bound) return false;
    const int k_first = row2 + slab_gap2(g, 2, q[2], c[2], -1) > bound ? c[2] : c[2] - 1;
    const int k_last = row2 + slab_gap2(g, 2, q[2], c[2], 1) > bound ? c[2] : c[2] + 1;
    scan_row(g, q, radius2, c[0] + di, c[1] + dj, k_first, k_last, -1, -1, visit);
    return false;
  };
  for_each_row_around(g, q, row);
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
constexpr int kMaxNeighbours = 32;

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

  // Squared distance a point must not exceed to enter: the k-th best once there are k.
  HOST_DEVICE float bound2(float radius2) const { return count == k ? d2[k - 1] : radius2; }
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
  HOST_DEVICE float bound2(float radius2) const { return best->bound2(radius2); }
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

// Unites `self` with every neighbour it is shown (same group). With for_each_forward_pair every
// edge is seen once; the small-fragment search instead shows each non-core point all its
// neighbours (for_each_within): every edge of a component without core points is then seen, and
// every non-core point of a component with one reaches a core point through non-core points, so
// these partial components decide "small or not" exactly.
template <class Ops>
struct UniteVisit {
  int32_t* parent;
  const int32_t* group;  // may be null
  int32_t self;
  Ops* ops;
  HOST_DEVICE void operator()(int32_t j, float) {
    if (j == self) return;
    if (group != nullptr && group[j] != group[self]) return;
    uf_unite(parent, self, j, *ops);
  }
};

// Small-fragment search (only components below a size matter): a point with at least `cap`
// neighbours (same group) lies in a component of at least cap + 1 points — a "core" point. The
// count stops as soon as it reaches cap, so dense regions cost a few candidates per point.
struct CapCountVisit {
  const int32_t* group;  // may be null
  int32_t self;
  int32_t cap;
  int32_t count = 0;
  HOST_DEVICE bool operator()(int32_t j, float) {
    if (j == self) return false;
    if (group != nullptr && group[j] != group[self]) return false;
    return ++count >= cap;
  }
};

}  // namespace spatial
}  // namespace fgs
