// OpenMP loops over particles for the constitutive models (csrc/common/constitutive.h).
#include "mpm/material_kernels.h"

#include "common/constitutive.h"
#include "common/svd3.h"
#include "mpm/constitutive_batch.h"

#include <algorithm>

namespace fgs {


int64_t constitutive_update_cpu(int64_t n, const float* F_trial, const float* alpha_in,
                                const float* material_table, int64_t n_materials,
                                const int32_t* material_id, float* F_out, float* alpha_out,
                                float* tau_out) {
  int64_t invalid = 0;
  const int64_t n_batches = (n + kBatchLanes - 1) / kBatchLanes;
#pragma omp parallel for schedule(static) reduction(+ : invalid)
  for (int64_t batch_index = 0; batch_index < n_batches; ++batch_index) {
    const int64_t first = batch_index * kBatchLanes;
    const int count = static_cast<int>(std::min<int64_t>(kBatchLanes, n - first));
    ConstitutiveBatch batch;
    bool known[kBatchLanes];
    int lanes = 0;  // particles with a valid material id, packed into the first lanes
    int64_t particle[kBatchLanes];
    for (int l = 0; l < count; ++l) {
      const int64_t i = first + l;
      const int32_t id = material_id[i];
      known[l] = id >= 0 && id < n_materials;
      if (!known[l]) continue;
      particle[lanes] = i;
      batch.set(lanes++, F_trial + 9 * i, alpha_in[i], material_table + kMatFields * static_cast<int64_t>(id));
    }
    batch.pad(lanes);
    batch.run(lanes);
    for (int l = 0; l < lanes; ++l) batch.get(l, F_out + 9 * particle[l], alpha_out + particle[l], tau_out + 9 * particle[l]);
    for (int l = 0; l < count; ++l) {
      if (known[l]) continue;
      constitutive_update_particle(first + l, F_trial, alpha_in, material_table, n_materials, material_id, F_out,
                                   alpha_out, tau_out);  // NaN outputs for the unknown id
      ++invalid;
    }
  }
  return invalid;
}

int64_t elastic_energy_cpu(int64_t n, const float* F, const float* material_table,
                           int64_t n_materials, const int32_t* material_id, float* psi) {
  int64_t invalid = 0;
#pragma omp parallel for schedule(static) reduction(+ : invalid)
  for (int64_t i = 0; i < n; ++i) {
    const int32_t id = material_id[i];
    if (id >= 0 && id < n_materials) {
      psi[i] = elastic_energy_density(material_table + kMatFields * static_cast<int64_t>(id), F + 9 * i);
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
