// CPU (OpenMP) spatial kernels: hash-grid build, fixed-radius k nearest, connected components.
// Deterministic for any thread count: the grid is built by a serial stable counting sort
// (O(N), a few ms for 1e6 points; the sorted copy of the points and their packed cells make the
// queries read contiguous memory), each query writes only its own row, and the union-find
// labels every component by its smallest index whatever order the unions run in.
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include "spatial/spatial_kernels.h"

namespace fgs {
namespace spatial {
namespace {

struct CpuAtomicOps {
  int32_t load(int32_t* p) const { return std::atomic_ref<int32_t>(*p).load(std::memory_order_relaxed); }
  bool cas(int32_t* p, int32_t expected, int32_t desired) const {
    return std::atomic_ref<int32_t>(*p).compare_exchange_strong(expected, desired,
                                                               std::memory_order_relaxed);
  }
};

}  // namespace

void build_grid_cpu(const float* points, int64_t num_points, HashGrid& g, int32_t* sorted_point,
                    int32_t* bucket_start, float* sorted_xyz, int64_t* sorted_cell) {
  const int64_t buckets = (int64_t)g.table_mask + 1;
  std::vector<uint32_t> bucket(num_points);
  std::vector<int64_t> key(num_points);
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < num_points; ++i) {
    int c[3];
    cell_of(g, points + 3 * i, c);
    bucket[i] = bucket_of(g, c[0], c[1], c[2]);
    key[i] = cell_key(c[0], c[1], c[2]);
  }
  for (int64_t b = 0; b <= buckets; ++b) bucket_start[b] = 0;
  for (int64_t i = 0; i < num_points; ++i) ++bucket_start[bucket[i] + 1];
  for (int64_t b = 0; b < buckets; ++b) bucket_start[b + 1] += bucket_start[b];
  std::vector<int32_t> cursor(bucket_start, bucket_start + buckets);
  for (int64_t i = 0; i < num_points; ++i) sorted_point[cursor[bucket[i]]++] = (int32_t)i;
#pragma omp parallel for schedule(static)
  for (int64_t s = 0; s < num_points; ++s) {
    const int64_t i = sorted_point[s];
    for (int a = 0; a < 3; ++a) sorted_xyz[3 * s + a] = points[3 * i + a];
    sorted_cell[s] = key[i];
  }
  g.sorted_point = sorted_point;
  g.bucket_start = bucket_start;
  g.sorted_xyz = sorted_xyz;
  g.sorted_cell = sorted_cell;
}

void knn_within_cpu(const HashGrid& g, const int32_t* point_group,
                    int64_t num_queries, const float* queries, const int32_t* query_group,
                    const int32_t* query_self, float radius, int k, int64_t* out_index,
                    float* out_distance) {
  const float radius2 = radius * radius;
#pragma omp parallel for schedule(dynamic, 256)
  for (int64_t q = 0; q < num_queries; ++q) {
    NearestK best;
    best.k = k;
    KnnVisit visit{&best, point_group, query_group != nullptr ? query_group[q] : 0,
                   query_self != nullptr ? query_self[q] : -1};
    for_each_nearer(g, queries + 3 * q, radius2, visit);
    for (int n = 0; n < k; ++n) {
      const bool found = n < best.count;
      out_index[q * k + n] = found ? best.index[n] : -1;
      out_distance[q * k + n] = found ? std::sqrt(best.d2[n]) : std::numeric_limits<float>::infinity();
    }
  }
}

void components_cpu(const HashGrid& g, const int32_t* group, int64_t num_points, float radius,
                    int32_t* parent, int32_t* labels) {
  const float radius2 = radius * radius;
  CpuAtomicOps ops;
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < num_points; ++i) parent[i] = (int32_t)i;
  // every edge once (forward half-neighbourhoods), in bucket (~ row-major cell) order so that
  // consecutive points read the same cells
#pragma omp parallel for schedule(dynamic, 256)
  for (int64_t s = 0; s < num_points; ++s) {
    UniteVisit<CpuAtomicOps> visit{parent, group, g.sorted_point[s], &ops};
    for_each_forward_pair(g, s, radius2, visit);
  }
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < num_points; ++i) labels[i] = uf_find(parent, (int32_t)i, ops);
}

void small_mask_cpu(const HashGrid& g, const int32_t* group,
                    int64_t num_points, float radius, int32_t min_size, const uint8_t* known_core,
                    int32_t* scratch, uint8_t* core, uint8_t* mask) {
  const float radius2 = radius * radius;
  const int32_t cap = min_size - 1;
  CpuAtomicOps ops;
  // the sorted slots of the points whose count is needed, those the hint does not name (bucket
  // order: neighbouring queries read the same cells)
  if (known_core != nullptr) std::memcpy(core, known_core, (size_t)num_points);
  else std::memset(core, 0, (size_t)num_points);
  std::vector<int64_t> counted;
  for (int64_t s = 0; s < num_points; ++s)
    if (!core[g.sorted_point[s]]) counted.push_back(s);
  const int64_t n_counted = (int64_t)counted.size();
#pragma omp parallel for schedule(dynamic, 256)
  for (int64_t t = 0; t < n_counted; ++t) {
    const int32_t i = g.sorted_point[counted[t]];
    CapCountVisit count{group, i, cap};
    for_each_within(g, g.sorted_xyz + 3 * counted[t], radius2, count);
    core[i] = count.count >= cap ? 1 : 0;
  }
  std::vector<int64_t> loose;  // sorted slots of the non-core points
  for (const int64_t s : counted)
    if (!core[g.sorted_point[s]]) loose.push_back(s);
  const int64_t n_loose = (int64_t)loose.size();
  std::memset(mask, 0, (size_t)num_points);
  if (n_loose == 0) return;
  // union-find over the non-core points only (scratch: their parents); a neighbour that is core
  // anchors the point, and with it its component, which is then not small
  std::vector<uint8_t> anchored(n_loose, 0);
  for (const int64_t s : loose) scratch[g.sorted_point[s]] = g.sorted_point[s];
#pragma omp parallel for schedule(dynamic, 256)
  for (int64_t t = 0; t < n_loose; ++t) {
    const int32_t i = g.sorted_point[loose[t]];
    auto visit = [&](int32_t j, float) {
      if (j == i || (group != nullptr && group[j] != group[i])) return;
      if (core[j]) anchored[t] = 1;
      else uf_unite(scratch, i, j, ops);
    };
    for_each_within(g, g.sorted_xyz + 3 * loose[t], radius2, visit);
  }
  std::vector<int32_t> root(n_loose);
#pragma omp parallel for schedule(static)
  for (int64_t t = 0; t < n_loose; ++t) root[t] = uf_find(scratch, g.sorted_point[loose[t]], ops);
  // per root (a non-core point): its points, or -1 once one of them is anchored; the parents
  // are no longer needed, so scratch holds these counts
  for (int64_t t = 0; t < n_loose; ++t) scratch[root[t]] = 0;
  for (int64_t t = 0; t < n_loose; ++t) {
    int32_t& slot = scratch[root[t]];
    if (anchored[t]) slot = -1;
    else if (slot >= 0) ++slot;
  }
  for (int64_t t = 0; t < n_loose; ++t) {
    const int32_t size = scratch[root[t]];
    mask[g.sorted_point[loose[t]]] = size >= 0 && size < min_size ? 1 : 0;
  }
}

void retained_neighbours_cpu(const float* points, int64_t num_points, int64_t num_queries,
                             const int64_t* rows, const int32_t* table, int k, float radius,
                             const uint8_t* full, int32_t stop_at, int32_t* kept) {
  const float radius2 = radius * radius;
#pragma omp parallel for schedule(static) if (num_queries >= 4096)
  for (int64_t q = 0; q < num_queries; ++q)
    kept[q] = retained_count(points, num_points, rows != nullptr ? rows[q] : q,
                             table + (int64_t)k * q, k, radius2,
                             full == nullptr || full[q] ? k : stop_at);
}

}  // namespace spatial
}  // namespace fgs
