// The CPU constitutive update, kBatchLanes particles at a time: the particles are laid out
// structure-of-arrays so that GCC's loop vectoriser turns constitutive_update_eig
// (csrc/common/hencky_eig.h) into vector code; particles that path does not handle (inverted
// or nearly singular F, non-finite input, unknown model) are redone one by one with the SVD
// path, constitutive_update (csrc/common/constitutive.h). Each particle's result depends only
// on its own inputs, never on the other lanes of its batch.
#pragma once
#include <cstdint>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "common/constitutive.h"
#include "common/hencky_eig.h"

namespace fgs {

constexpr int kBatchLanes = 16;

// Flushes denormal inputs and results to zero while alive (x86; a no-op elsewhere). The Jacobi
// sweeps of a nearly undeformed particle (strain ~1e-7) square the off-diagonal terms down into
// the denormal range, where every operation takes a ~100-cycle microcode assist: without this
// guard such particles cost ~40 % more. Values below 1.2e-38 (float) / 2.2e-308 (double)
// become 0, which changes no result that matters.
class FlushDenormals {
 public:
#if defined(__SSE__)
  FlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040); }  // FTZ | DAZ
  ~FlushDenormals() { _mm_setcsr(saved_); }

 private:
  unsigned int saved_;
#endif
};

struct ConstitutiveBatch {
  float F[9][kBatchLanes];  // F_trial (input)
  float alpha_in[kBatchLanes];
  float row[kMatFields][kBatchLanes];  // material parameters of each lane
  float F_out[9][kBatchLanes];
  float alpha_out[kBatchLanes];
  float tau[9][kBatchLanes];
  int32_t valid[kBatchLanes];  // 1 where the eigen path handled the lane (int32: a bool store blocks vectorising)

  // Lane l takes F_trial, alpha and a material-table row (kMatFields floats).
  void set(int l, const float* F_trial, float alpha, const float* mat_row) {
    #pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) F[i][l] = F_trial[i];
    alpha_in[l] = alpha;
    #pragma GCC unroll 9
    for (int k = 0; k < kMatFields; ++k) row[k][l] = mat_row[k];
  }

  // Lanes [count, kBatchLanes) get an undeformed elastic particle (results unused).
  void pad(int count) {
    for (int l = count; l < kBatchLanes; ++l) {
      #pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) F[i][l] = (i % 4 == 0) ? 1.f : 0.f;
      alpha_in[l] = 0.f;
      #pragma GCC unroll 9
      for (int k = 0; k < kMatFields; ++k) row[k][l] = 0.f;
      row[kMatModel][l] = static_cast<float>(kModelElastic);
    }
  }

  // Runs the update on lanes [0, count) (pad() the rest first).
  void run(int count) {
    {
      FlushDenormals guard;
      eigen_lanes(&F[0][0], alpha_in, &row[0][0], &F_out[0][0], alpha_out, &tau[0][0], valid);
    }
    for (int l = 0; l < count; ++l) {
      if (valid[l]) continue;
      float Fl[9], tl[9], mat_row[kMatFields];
      for (int i = 0; i < 9; ++i) Fl[i] = F[i][l];
      for (int k = 0; k < kMatFields; ++k) mat_row[k] = row[k][l];
      float a = alpha_in[l];
      constitutive_update(mat_row, Fl, &a, tl);
      for (int i = 0; i < 9; ++i) {
        F_out[i][l] = Fl[i];
        tau[i][l] = tl[i];
      }
      alpha_out[l] = a;
    }
  }

  // constitutive_update_eig on every lane; arrays are [component][lane].
  static void eigen_lanes(const float* FGS_RESTRICT F_in, const float* FGS_RESTRICT alpha,
                          const float* FGS_RESTRICT rows, float* FGS_RESTRICT F_E, float* FGS_RESTRICT alpha_new,
                          float* FGS_RESTRICT tau_out, int32_t* FGS_RESTRICT ok) {
    // `#pragma omp simd` would turn the callee's by-reference locals into per-lane arrays before
    // inlining and then fail to vectorise; the plain vectoriser after inlining does not.
#pragma GCC ivdep
    for (int l = 0; l < kBatchLanes; ++l) {
      float Fl[9], Fo[9], tl[9];
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) Fl[i] = F_in[i * kBatchLanes + l];
      const MaterialRow m{rows[kMatModel * kBatchLanes + l], rows[kMatMu * kBatchLanes + l],
                          rows[kMatLambda * kBatchLanes + l], rows[kMatBulk * kBatchLanes + l],
                          rows[kMatBeta * kBatchLanes + l], rows[kMatXi * kBatchLanes + l],
                          rows[kMatM * kBatchLanes + l]};
      float a = alpha[l];
      ok[l] = constitutive_update_eig(m, Fl, &a, Fo, tl) ? 1 : 0;
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) {
        F_E[i * kBatchLanes + l] = Fo[i];
        tau_out[i * kBatchLanes + l] = tl[i];
      }
      alpha_new[l] = a;
    }
  }

  void get(int l, float* F_E, float* alpha, float* tau_out) const {
    #pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) {
      F_E[i] = F_out[i][l];
      tau_out[i] = tau[i][l];
    }
    *alpha = alpha_out[l];
  }
};

}  // namespace fgs
