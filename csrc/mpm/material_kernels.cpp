// OpenMP loops over particles for the constitutive models (csrc/common/constitutive.h).
#include "mpm/material_kernels.h"

#include "common/constitutive.h"
#include "common/svd3.h"
#include "mpm/constitutive_batch.h"

#include <algorithm>

namespace fgs {


int64_t constitutive_update_cpu(int64_t n, const float* F_trial, const float* alpha_in, const float* strength,
                                const float* material_table, int64_t n_materials,
                                const int32_t* material_id, float* F_out, float* alpha_out,
                                float* tau_out) {
  int64_t invalid = 0;
#pragma omp parallel reduction(+ : invalid)
  {
    ConstitutiveStream stream;
    auto store = [&](long long i, const float F_E[9], float alpha, const float tau[9], float) {
      for (int k = 0; k < 9; ++k) {
        F_out[9 * i + k] = F_E[k];
        tau_out[9 * i + k] = tau[k];
      }
      alpha_out[i] = alpha;
    };
#pragma omp for schedule(dynamic, 512) nowait  // per-particle results: any schedule gives the same bits
    for (int64_t i = 0; i < n; ++i) {
      const int32_t id = material_id[i];
      if (id >= 0 && id < n_materials) {
        const float* row = material_table + kMatFields * static_cast<int64_t>(id);
        stream.push(i, F_trial + 9 * i, alpha_in[i], row, particle_strength(strength, i, row), store);
      } else {
        constitutive_update_particle(i, F_trial, alpha_in, strength, material_table, n_materials, material_id, F_out,
                                     alpha_out, tau_out);  // NaN outputs for the unknown id
        ++invalid;
      }
    }
    stream.finish(store);
  }
  return invalid;
}

int64_t elastic_energy_cpu(int64_t n, const float* F, const float* alpha, const float* material_table,
                           int64_t n_materials, const int32_t* material_id, float* psi) {
  int64_t invalid = 0;
#pragma omp parallel for schedule(static) reduction(+ : invalid)
  for (int64_t i = 0; i < n; ++i) {
    const int32_t id = material_id[i];
    if (id >= 0 && id < n_materials) {
      psi[i] = elastic_energy_density(material_table + kMatFields * static_cast<int64_t>(id), F + 9 * i, alpha[i]);
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

}  // namespace fgs
