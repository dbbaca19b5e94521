// OpenMP loops over particles for the material models (csrc/common/constitutive.h and the batched
// paths of csrc/mpm/constitutive_batch.h).
#include "mpm/material_kernels.h"

#include "common/constitutive.h"
#include "common/svd3.h"
#include "mpm/constitutive_batch.h"

#include <algorithm>

namespace fgs {


int64_t constitutive_update_cpu(int64_t n, const float* F_trial, const float* state_in, int stride,
                                const float* material_table, int64_t n_materials, const int32_t* material_id,
                                float* F_out, float* state_out, float* tau_out, float* dissipated) {
  int64_t invalid = 0;
#pragma omp parallel reduction(+ : invalid)
  {
    ConstitutiveStream stream;
    auto store = [&](long long i, const float F_E[9], const float* state, const float tau[9], float taken) {
      for (int k = 0; k < 9; ++k) {
        F_out[9 * i + k] = F_E[k];
        tau_out[9 * i + k] = tau[k];
      }
      store_state(state, stride, i, state_out);
      dissipated[i] = taken;
    };
#pragma omp for schedule(dynamic, 512) nowait  // per-particle results: any schedule gives the same bits
    for (int64_t i = 0; i < n; ++i) {
      const int32_t id = material_id[i];
      if (id >= 0 && id < n_materials) {
        stream.push(i, F_trial + 9 * i, state_in + static_cast<int64_t>(stride) * i, stride,
                    material_table + kMatFields * static_cast<int64_t>(id), store);
      } else {
        constitutive_update_particle(i, F_trial, state_in, stride, material_table, n_materials, material_id, F_out,
                                     state_out, tau_out, dissipated);  // NaN outputs for the unknown id
        ++invalid;
      }
    }
    stream.finish(store);
  }
  return invalid;
}

int64_t elastic_energy_cpu(int64_t n, const float* F, const float* state, int stride, const float* material_table,
                           int64_t n_materials, const int32_t* material_id, float* psi) {
  int64_t invalid = 0;
#pragma omp parallel for schedule(static) reduction(+ : invalid)
  for (int64_t i = 0; i < n; ++i) {
    const int32_t id = material_id[i];
    if (id >= 0 && id < n_materials) {
      float particle_state[kMaxStateFields];
      load_state(state, stride, i, particle_state);
      psi[i] = elastic_energy_density(material_table + kMatFields * static_cast<int64_t>(id), F + 9 * i,
                                      particle_state);
    } else {
      psi[i] = NAN;
      ++invalid;
    }
  }
  return invalid;
}

void svd3_batch_cpu(int64_t n, const float* F, float* U, float* sigma, float* V) {
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i) svd3(F + 9 * i, U + 9 * i, sigma + 3 * i, V + 9 * i);
}

void advance_split_directions_cpu(int64_t n, float* state, int stride, const float* trigger_old, const float* C,
                                  const float* F_E, const uint8_t* mine, const SplitDirectionParams& params) {
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i)
    if (mine[i]) split_direction_step(state + static_cast<int64_t>(stride) * i, trigger_old[i], C + 9 * i, F_E + 9 * i,
                                      params);
}

}  // namespace fgs
