// Uniform hash grid for fixed-radius neighbour queries, shared by the CPU and CUDA kernels.
//
// Space is cut into cubic cells of edge `cell` (>= the query radius, so a query looks at the 27
// cells around it). A cell (i, j, k) goes to bucket hash(i, j, k) mod table_size (Teschner et
// al. 2003 primes; table_size a power of two). Points are sorted by bucket, ties by index
// (stable), and bucket_start[b] .. bucket_start[b + 1] lists bucket b's points. Different cells
// can share a bucket: a query checks every candidate's own cell against the cell it looks at,
// so each point is met at most once and the results do not depend on collisions.
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
  const int32_t* sorted_point;    // (P,) point indices in bucket order
  const int32_t* bucket_start;    // (table_size + 1,)
};

HOST_DEVICE inline void cell_of(const HashGrid& g, const float* p, int c[3]) {
  for (int a = 0; a < 3; ++a) c[a] = static_cast<int>(floorf((p[a] - g.origin[a]) * g.inv_cell));
}

HOST_DEVICE inline uint32_t bucket_of(const HashGrid& g, int i, int j, int k) {
  const uint32_t h = (static_cast<uint32_t>(i) * 73856093u) ^ (static_cast<uint32_t>(j) * 19349663u) ^
                     (static_cast<uint32_t>(k) * 83492791u);
  return h & g.table_mask;
}

HOST_DEVICE inline float distance2(const float* a, const float* b) {
  const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
  return dx * dx + dy * dy + dz * dz;
}

// Calls visit(j, d2) for every grid point j with |x_j - q|^2 <= radius2 (radius <= cell).
// Order: cells by (dz, dy, dx) from -1 to 1, inside a cell by point index.
template <class Visit>
HOST_DEVICE inline void for_each_within(const HashGrid& g, const float* points, const float* q,
                                        float radius2, Visit& visit) {
  int c[3];
  cell_of(g, q, c);
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const int ci = c[0] + dx, cj = c[1] + dy, ck = c[2] + dz;
        const uint32_t b = bucket_of(g, ci, cj, ck);
        for (int32_t s = g.bucket_start[b]; s < g.bucket_start[b + 1]; ++s) {
          const int32_t j = g.sorted_point[s];
          const float* pj = points + 3 * (int64_t)j;
          int cj3[3];
          cell_of(g, pj, cj3);
          if (cj3[0] != ci || cj3[1] != cj || cj3[2] != ck) continue;  // hash collision
          const float d2 = distance2(pj, q);
          if (d2 <= radius2) visit(j, d2);
        }
      }
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
    if (j <= self) return;  // each edge once, from its smaller end
    if (group != nullptr && group[j] != group[self]) return;
    uf_unite(parent, self, j, *ops);
  }
};

}  // namespace spatial
}  // namespace fgs
