// CUDA spatial kernels; the same per-query math as spatial_cpu.cpp (hash_grid.h). The grid is
// sorted by the binding (torch sort of bucket << 32 | index keys, so ties keep index order,
// then the points and their packed cells gathered into that order);
// queries run one thread each; the union-find uses atomicCAS and, as on the CPU, labels every
// component by its smallest index whatever order the unions run in.
#include <cuda_runtime.h>

#include <cmath>

#include "spatial/spatial_kernels.h"

namespace fgs {
namespace spatial {
namespace {

constexpr int kThreads = 256;

// Host-device so that the HOST_DEVICE union-find templates instantiate cleanly; only the
// device branch ever runs.
struct CudaAtomicOps {
  __host__ __device__ int32_t load(int32_t* p) const { return *((volatile int32_t*)p); }
  __host__ __device__ bool cas(int32_t* p, int32_t expected, int32_t desired) const {
#ifdef __CUDA_ARCH__
    return atomicCAS(p, expected, desired) == expected;
#else
    if (*p != expected) return false;
    *p = desired;
    return true;
#endif
  }
};

int blocks_for(int64_t n) { return (int)((n + kThreads - 1) / kThreads); }

__global__ void bucket_keys_kernel(HashGrid g, const float* points, int64_t num, int64_t* keys,
                                   int64_t* cells) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= num) return;
  int c[3];
  cell_of(g, points + 3 * i, c);
  keys[i] = ((int64_t)bucket_of(g, c[0], c[1], c[2]) << 32) | i;
  cells[i] = cell_key(c[0], c[1], c[2]);
}

__global__ void knn_kernel(HashGrid g, const int32_t* point_group,
                           int64_t num_queries, const float* queries, const int32_t* query_group,
                           const int32_t* query_self, float radius, int k, int64_t* out_index,
                           float* out_distance) {
  const int64_t q = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (q >= num_queries) return;
  NearestK best;
  best.k = k;
  KnnVisit visit{&best, point_group, query_group != nullptr ? query_group[q] : 0,
                 query_self != nullptr ? query_self[q] : -1};
  for_each_nearer(g, queries + 3 * q, radius * radius, visit);
  for (int n = 0; n < k; ++n) {
    const bool found = n < best.count;
    out_index[q * k + n] = found ? best.index[n] : -1;
    out_distance[q * k + n] = found ? sqrtf(best.d2[n]) : INFINITY;
  }
}

__global__ void init_parent_kernel(int64_t num, int32_t* parent) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < num) parent[i] = (int32_t)i;
}

__global__ void unite_kernel(HashGrid g, const int32_t* group, int64_t num, float radius,
                             int32_t* parent) {
  const int64_t s = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;  // bucket order
  if (s >= num) return;
  CudaAtomicOps ops;
  UniteVisit<CudaAtomicOps> visit{parent, group, g.sorted_point[s], &ops};
  for_each_forward_pair(g, s, radius * radius, visit);
}

__global__ void label_kernel(int64_t num, int32_t* parent, int32_t* labels) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= num) return;
  CudaAtomicOps ops;
  labels[i] = uf_find(parent, (int32_t)i, ops);
}

__global__ void core_kernel(HashGrid g, const int32_t* group, int64_t num, float radius,
                            int32_t cap, const uint8_t* known_core, int32_t* parent,
                            uint8_t* core) {
  const int64_t s = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;  // bucket order
  if (s >= num) return;
  const int32_t i = g.sorted_point[s];
  parent[i] = i;
  if (known_core != nullptr && known_core[i]) {
    core[i] = 1;
    return;
  }
  CapCountVisit count{group, i, cap};
  for_each_within(g, g.sorted_xyz + 3 * s, radius * radius, count);
  core[i] = count.count >= cap ? 1 : 0;
}

__global__ void unite_non_core_kernel(HashGrid g, const int32_t* group, int64_t num, float radius,
                                      const uint8_t* core, int32_t* parent) {
  const int64_t s = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (s >= num) return;
  const int32_t i = g.sorted_point[s];
  if (core[i]) return;
  CudaAtomicOps ops;
  UniteVisit<CudaAtomicOps> visit{parent, group, i, &ops};
  for_each_within(g, g.sorted_xyz + 3 * s, radius * radius, visit);
}

__global__ void retained_kernel(const float* points, int64_t num_points, int64_t num_queries,
                                const int64_t* rows,
                                const int32_t* table, int k, float radius2, const uint8_t* full,
                                int32_t stop_at, int32_t* kept) {
  const int64_t q = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (q >= num_queries) return;
  kept[q] = retained_count(points, num_points, rows != nullptr ? rows[q] : q,
                           table + (int64_t)k * q, k, radius2,
                           full == nullptr || full[q] ? k : stop_at);
}

}  // namespace

void bucket_keys_cuda(const HashGrid& g, const float* points, int64_t num_points, int64_t* keys,
                      int64_t* cells, void* stream) {
  if (num_points == 0) return;
  bucket_keys_kernel<<<blocks_for(num_points), kThreads, 0, (cudaStream_t)stream>>>(
      g, points, num_points, keys, cells);
}

void knn_within_cuda(const HashGrid& g, const int32_t* point_group,
                     int64_t num_queries, const float* queries, const int32_t* query_group,
                     const int32_t* query_self, float radius, int k, int64_t* out_index,
                     float* out_distance, void* stream) {
  if (num_queries == 0) return;
  knn_kernel<<<blocks_for(num_queries), kThreads, 0, (cudaStream_t)stream>>>(
      g, point_group, num_queries, queries, query_group, query_self, radius, k, out_index,
      out_distance);
}

void components_cuda(const HashGrid& g, const int32_t* group, int64_t num_points, float radius,
                     int32_t* parent, int32_t* labels, void* stream) {
  if (num_points == 0) return;
  const cudaStream_t s = (cudaStream_t)stream;
  init_parent_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(num_points, parent);
  unite_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(g, group, num_points, radius, parent);
  label_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(num_points, parent, labels);
}

void small_components_cuda(const HashGrid& g, const int32_t* group, int64_t num_points,
                           float radius, int32_t cap, const uint8_t* known_core, int32_t* parent,
                           uint8_t* core, int32_t* labels, void* stream) {
  if (num_points == 0) return;
  const cudaStream_t s = (cudaStream_t)stream;
  core_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(g, group, num_points, radius, cap,
                                                          known_core, parent, core);
  unite_non_core_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(g, group, num_points, radius,
                                                                    core, parent);
  label_kernel<<<blocks_for(num_points), kThreads, 0, s>>>(num_points, parent, labels);
}

void retained_neighbours_cuda(const float* points, int64_t num_points, int64_t num_queries,
                              const int64_t* rows, const int32_t* table, int k, float radius,
                              const uint8_t* full, int32_t stop_at, int32_t* kept, void* stream) {
  if (num_queries == 0) return;
  retained_kernel<<<blocks_for(num_queries), kThreads, 0, (cudaStream_t)stream>>>(
      points, num_points, num_queries, rows, table, k, radius * radius, full, stop_at, kept);
}

}  // namespace spatial
}  // namespace fgs
