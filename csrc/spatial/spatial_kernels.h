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
// Small fragments without the full component labelling: core (N) = 1 where a point has at least
// `cap` neighbours (counting stops there), then non-core points are united with all their
// neighbours; labels (N) = the root of each point in that partial union-find. A point lies in a
// component of fewer than cap + 1 points iff it is not core and no core point shares its label
// (the binding turns this into the mask). parent (N) is scratch.
// `known_core` (N, may be null): points the caller knows to have at least `cap` neighbours
// (e.g. from retained_neighbours_cpu); their count is not taken. Only a hint: the result is
// the same with or without it, as long as it names true core points only.
void small_components_cpu(const HashGrid& g, const int32_t* group, int64_t num_points, float radius,
                          int32_t cap, const uint8_t* known_core, int32_t* parent, uint8_t* core,
                          int32_t* labels);
// mask (N) = 1 where a point is not core, no core point shares its label and fewer than
// min_size points do: the small-fragment mask from small_components_cpu's labels and core;
// scratch (N) is overwritten (it may be small_components_cpu's parent buffer).
void small_mask_from_labels_cpu(int64_t num_points, const int32_t* labels, const uint8_t* core,
                                int32_t min_size, int32_t* scratch, uint8_t* mask);
// kept (Q) = retained_count (hash_grid.h) of point rows[q] (q itself when rows is null) against
// table row q (Q, k): the full count where full[q] (or full is null), else stopped at stop_at.
void retained_neighbours_cpu(const float* points, int64_t num_queries, const int64_t* rows,
                             const int32_t* table, int k, float radius, const uint8_t* full,
                             int32_t stop_at, int32_t* kept);

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
void small_components_cuda(const HashGrid& g, const int32_t* group, int64_t num_points,
                           float radius, int32_t cap, const uint8_t* known_core, int32_t* parent,
                           uint8_t* core, int32_t* labels, void* stream);
void retained_neighbours_cuda(const float* points, int64_t num_queries, const int64_t* rows,
                              const int32_t* table, int k, float radius, const uint8_t* full,
                              int32_t stop_at, int32_t* kept, void* stream);
#endif

}  // namespace spatial
}  // namespace fgs
