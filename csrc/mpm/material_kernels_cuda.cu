// CUDA twins of material_kernels.cpp: one thread per particle, same header math.
#include <cuda_runtime.h>

#include "common/constitutive.h"
#include "common/svd3.h"
#include "mpm/material_kernels.h"

namespace fgs {

namespace {

constexpr int kThreads = 128;

inline unsigned int blocks_for(int64_t n) {
  return static_cast<unsigned int>((n + kThreads - 1) / kThreads);
}

__global__ void constitutive_update_kernel(int64_t n, const float* __restrict__ F_trial, const float* state_in,
                                           int stride, const float* __restrict__ material_table, int64_t n_materials,
                                           const int32_t* __restrict__ material_id, float* F_out, float* state_out,
                                           float* __restrict__ tau_out, float* __restrict__ dissipated) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  constitutive_update_particle(i, F_trial, state_in, stride, material_table, n_materials, material_id, F_out,
                               state_out, tau_out, dissipated);
}

__global__ void elastic_energy_kernel(int64_t n, const float* __restrict__ F, const float* __restrict__ state,
                                      int stride, const float* __restrict__ material_table, int64_t n_materials,
                                      const int32_t* __restrict__ material_id, float* __restrict__ psi) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int32_t id = material_id[i];
  float particle_state[kMaxStateFields];
  load_state(state, stride, i, particle_state);
  psi[i] = (id >= 0 && id < n_materials)
               ? elastic_energy_density(material_table + kMatFields * static_cast<int64_t>(id), F + 9 * i,
                                        particle_state)
               : NAN;
}

__global__ void svd3_batch_kernel(int64_t n, const float* __restrict__ F, float* __restrict__ U,
                                  float* __restrict__ sigma, float* __restrict__ V) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  svd3(F + 9 * i, U + 9 * i, sigma + 3 * i, V + 9 * i);
}

__global__ void advance_split_directions_kernel(int64_t n, float* state, int stride,
                                                const float* __restrict__ trigger_old, const float* __restrict__ C,
                                                const float* __restrict__ F_E, const uint8_t* __restrict__ mine,
                                                SplitDirectionParams params) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n || !mine[i]) return;
  split_direction_step(state + static_cast<int64_t>(stride) * i, trigger_old[i], C + 9 * i, F_E + 9 * i, params);
}

}  // namespace

void constitutive_update_cuda(int64_t n, const float* F_trial, const float* state_in, int stride,
                              const float* material_table, int64_t n_materials, const int32_t* material_id,
                              float* F_out, float* state_out, float* tau_out, float* dissipated, void* stream) {
  if (n == 0) return;
  constitutive_update_kernel<<<blocks_for(n), kThreads, 0, static_cast<cudaStream_t>(stream)>>>(
      n, F_trial, state_in, stride, material_table, n_materials, material_id, F_out, state_out, tau_out, dissipated);
}

void elastic_energy_cuda(int64_t n, const float* F, const float* state, int stride, const float* material_table,
                         int64_t n_materials, const int32_t* material_id, float* psi, void* stream) {
  if (n == 0) return;
  elastic_energy_kernel<<<blocks_for(n), kThreads, 0, static_cast<cudaStream_t>(stream)>>>(
      n, F, state, stride, material_table, n_materials, material_id, psi);
}

void svd3_batch_cuda(int64_t n, const float* F, float* U, float* sigma, float* V, void* stream) {
  if (n == 0) return;
  svd3_batch_kernel<<<blocks_for(n), kThreads, 0, static_cast<cudaStream_t>(stream)>>>(n, F, U, sigma, V);
}

void advance_split_directions_cuda(int64_t n, float* state, int stride, const float* trigger_old, const float* C,
                                   const float* F_E, const uint8_t* mine, const SplitDirectionParams& params,
                                   void* stream) {
  if (n == 0) return;
  advance_split_directions_kernel<<<blocks_for(n), kThreads, 0, static_cast<cudaStream_t>(stream)>>>(
      n, state, stride, trigger_old, C, F_E, mine, params);
}

}  // namespace fgs
