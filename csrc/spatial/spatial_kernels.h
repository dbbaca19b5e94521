// Framework-free interface of the spatial kernels: fixed-radius k-nearest neighbours and
// connected components of the radius graph, on the uniform hash grid of hash_grid.h.
// Raw pointers, float32 points (N, 3) row-major, int32 indices. The binding
// (spatial_bind.cpp) allocates every buffer.
#pragma once
#include <cstdint>

#include "spatial/hash_grid.h"

namespace fgs {
namespace spatial {

// ---- CPU (OpenMP) ---------------------------------------------------------------------
// Fills sorted_point (P), bucket_start (mask + 2), sorted_xyz (P, 3) and sorted_cell (P) of g
// (origin, inv_cell, table_mask set). Counting sort: stable, so the bucket lists are in
// point-index order (deterministic).
void build_grid_cpu(const float* points, int64_t num_points, HashGrid& g, int32_t* sorted_point,
                    int32_t* bucket_start, float* sorted_xyz, int64_t* sorted_cell);
// For each query: the k nearest grid points within radius (same group when groups are given,
// never the query's `self` point), sorted by (distance, index); -1 / inf pad the rows.
void knn_within_cpu(const HashGrid& g, const int32_t* point_group,
                    int64_t num_queries, const float* queries, const int32_t* query_group,
                    const int32_t* query_self, float radius, int k, int64_t* out_index,
                    float* out_distance);
// labels (N) = the smallest point index of each point's component (edges: distance <= radius,
// same group when groups are given); parent (N) is scratch. Points and grid points are the
// same set.
void components_cpu(const HashGrid& g, const int32_t* group, int64_t num_points, float radius,
                    int32_t* parent, int32_t* labels);
// mask (N) = 1 where a point lies in a component (edges: distance <= radius, same group) of
// fewer than min_size points, found without labelling the large bodies: a point is core when
// known_core names it (may be null; only a hint, it must name true core points only: at least
// min_size - 1 neighbours, e.g. from retained_neighbours_cpu) or its count, which stops there,
// reaches min_size - 1. Only the other points are united, among themselves; one with a core
// neighbour anchors its component, which is then not small. scratch (N) int32 and core (N) are
// overwritten (of scratch only the non-core points' entries).
void small_mask_cpu(const HashGrid& g, const int32_t* group,
                    int64_t num_points, float radius, int32_t min_size, const uint8_t* known_core,
                    int32_t* scratch, uint8_t* core, uint8_t* mask);
// kept (Q) = retained_count (hash_grid.h) of point rows[q] (q itself when rows is null) against
// table row q (Q, k): the full count where full[q] (or full is null), else stopped at stop_at;
// kInvalidTableEntry where an entry it read does not index the num_points points.
void retained_neighbours_cpu(const float* points, int64_t num_points, int64_t num_queries,
                             const int64_t* rows, const int32_t* table, int k, float radius,
                             const uint8_t* full, int32_t stop_at, int32_t* kept);
// ---- CUDA (raw device pointers; stream is a cudaStream_t passed as void*) ---------------
#ifdef FGS_WITH_CUDA
// keys[i] = bucket << 32 | i (sorted by the binding), cells[i] = cell_key of point i.
void bucket_keys_cuda(const HashGrid& g, const float* points, int64_t num_points, int64_t* keys,
                      int64_t* cells, void* stream);
void knn_within_cuda(const HashGrid& g, const int32_t* point_group,
                     int64_t num_queries, const float* queries, const int32_t* query_group,
                     const int32_t* query_self, float radius, int k, int64_t* out_index,
                     float* out_distance, void* stream);
void components_cuda(const HashGrid& g, const int32_t* group, int64_t num_points, float radius,
                     int32_t* parent, int32_t* labels, void* stream);
// The CUDA form of small_mask_cpu in two steps: core (N) as there, non-core points united with
// all their neighbours (core ones included), labels (N) = each point's root in that partial
// union-find (parent (N) is scratch); the binding keeps the non-core points of labels without a
// core point and of fewer than min_size points (cap = min_size - 1).
void small_components_cuda(const HashGrid& g, const int32_t* group, int64_t num_points,
                           float radius, int32_t cap, const uint8_t* known_core, int32_t* parent,
                           uint8_t* core, int32_t* labels, void* stream);
void retained_neighbours_cuda(const float* points, int64_t num_points, int64_t num_queries,
                              const int64_t* rows, const int32_t* table, int k, float radius,
                              const uint8_t* full, int32_t stop_at, int32_t* kept, void* stream);
#endif

}  // namespace spatial
}  // namespace fgs
