// Per-particle material kernels (raw pointers, no torch): the OpenMP versions are in
// material_kernels.cpp, the CUDA launchers (one thread per particle) in material_kernels_cuda.cu.
// Layouts: F, U, V, tau (n, 3, 3) row-major float32; state (n, stride) float32 (the material state,
// csrc/common/material_law.h); psi, dissipated (n,); sigma (n, 3); material_table (n_materials,
// kMatFields) float32; material_id (n,) int32.
// A particle whose material_id is outside [0, n_materials) gets NaN outputs.
#pragma once
#include <cstdint>

#include "common/split_direction.h"

namespace fgs {

// The update (F_E, new state, Kirchhoff stress, dissipated energy per unit rest volume) of every
// particle. F_out/state_out may alias F_trial/state_in. Returns the number of particles with an
// invalid material_id.
int64_t constitutive_update_cpu(int64_t n, const float* F_trial, const float* state_in, int stride,
                                const float* material_table, int64_t n_materials, const int32_t* material_id,
                                float* F_out, float* state_out, float* tau_out, float* dissipated);

// psi(F_E) per unit rest volume at each particle's state. Returns the number of particles with an
// invalid material_id.
int64_t elastic_energy_cpu(int64_t n, const float* F, const float* state, int stride, const float* material_table,
                           int64_t n_materials, const int32_t* material_id, float* psi);

// F = U diag(sigma) V^T for a batch (exposed for tests).
void svd3_batch_cpu(int64_t n, const float* F, float* U, float* sigma, float* V);

// split_direction_step (csrc/common/split_direction.h) on every particle with mine[i] != 0: state
// (n, stride) changed in place; trigger_old (n,); C, F_E (n, 3, 3).
void advance_split_directions_cpu(int64_t n, float* state, int stride, const float* trigger_old, const float* C,
                                  const float* F_E, const uint8_t* mine, const SplitDirectionParams& params);

#ifdef FGS_WITH_CUDA
// CUDA launchers; pointers are device pointers, stream is a cudaStream_t passed as void*.
void constitutive_update_cuda(int64_t n, const float* F_trial, const float* state_in, int stride,
                              const float* material_table, int64_t n_materials, const int32_t* material_id,
                              float* F_out, float* state_out, float* tau_out, float* dissipated, void* stream);
void elastic_energy_cuda(int64_t n, const float* F, const float* state, int stride, const float* material_table,
                         int64_t n_materials, const int32_t* material_id, float* psi, void* stream);
void svd3_batch_cuda(int64_t n, const float* F, float* U, float* sigma, float* V, void* stream);
void advance_split_directions_cuda(int64_t n, float* state, int stride, const float* trigger_old, const float* C,
                                   const float* F_E, const uint8_t* mine, const SplitDirectionParams& params,
                                   void* stream);
#endif

}  // namespace fgs
