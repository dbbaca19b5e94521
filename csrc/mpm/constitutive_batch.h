// The CPU constitutive update, kBatchLanes particles at a time: the particles are laid out
// structure-of-arrays so that GCC's loop vectoriser turns constitutive_small_strain and the eigen
// path, constitutive_stress_eig + projected_deformation (csrc/common/hencky_eig.h), into vector
// code. ConstitutiveStream (at the end) runs the first and sends what it rejects to the second;
// particles the eigen path does not handle (inverted or nearly singular F, non-finite input,
// unknown model) are redone one by one with the SVD path, constitutive_update
// (csrc/common/constitutive.h). Each particle's result depends only on its own inputs, never on
// the other lanes of its batch.
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
  // The lanes' states: the fields a stream's particles do not have (beyond its stride) stay 0.
  float state_in[kMaxStateFields][kBatchLanes] = {};
  float row[kMatFields][kBatchLanes];  // material parameters of each lane
  float F_out[9][kBatchLanes];
  float state_out[kMaxStateFields][kBatchLanes];
  float tau[9][kBatchLanes];
  float dissipated[kBatchLanes];  // energy per unit rest volume the update took (output)
  int32_t valid[kBatchLanes];  // 1 where the eigen path handled the lane (int32: a bool store blocks vectorising)

  // Lane l takes F_trial, the particle's state (stride floats, stride the same for every lane of
  // the batch's life) and its material-table row (kMatFields floats).
  void set(int l, const float* F_trial, const float* state, int stride, const float* mat_row) {
    #pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) F[i][l] = F_trial[i];
    for (int k = 0; k < stride; ++k) state_in[k][l] = state[k];
    #pragma GCC unroll 9
    for (int k = 0; k < kMatFields; ++k) row[k][l] = mat_row[k];
  }

  // Lanes [count, kBatchLanes) (count >= 1) get an undeformed particle with lane 0's material and
  // a zero state (results unused), so that a batch of one model stays one.
  void pad(int count) {
    for (int l = count; l < kBatchLanes; ++l) {
      #pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) F[i][l] = (i % 4 == 0) ? 1.f : 0.f;
      #pragma GCC unroll 9
      for (int k = 0; k < kMaxStateFields; ++k) state_in[k][l] = 0.f;
      #pragma GCC unroll 9
      for (int k = 0; k < kMatFields; ++k) row[k][l] = row[k][0];
    }
  }

  // Calls run(Laws{}) with OneModel<Model> where every lane has that model (the common case: objects
  // are contiguous), else with MaterialModels.
  template <class Run>
  void with_laws(Run&& run) const {
    const float code = row[kMatModel][0];
    bool one = true;
    for (int l = 1; l < kBatchLanes; ++l) one = one && row[kMatModel][l] == code;
    const bool dispatched = one && MaterialModels::visit_code(code, [&](auto model) {
      run(OneModel<decltype(model)>{});
    });
    if (!dispatched) run(MaterialModels{});
  }

  // Runs the update on lanes [0, count) (pad() the rest first).
  void run(int count) {
    with_laws([&](auto laws) {
      FlushDenormals guard;
      eigen_lanes<decltype(laws)>(&F[0][0], &state_in[0][0], &row[0][0], &F_out[0][0], &state_out[0][0], &tau[0][0],
                                  dissipated, valid);
    });
    for (int l = 0; l < count; ++l) {
      if (valid[l]) continue;
      float Fl[9], tl[9], mat_row[kMatFields], state[kMaxStateFields];
      for (int i = 0; i < 9; ++i) Fl[i] = F[i][l];
      for (int k = 0; k < kMatFields; ++k) mat_row[k] = row[k][l];
      for (int k = 0; k < kMaxStateFields; ++k) state[k] = state_in[k][l];
      constitutive_update(mat_row, Fl, state, tl, &dissipated[l]);
      for (int i = 0; i < 9; ++i) {
        F_out[i][l] = Fl[i];
        tau[i][l] = tl[i];
      }
      for (int k = 0; k < kMaxStateFields; ++k) state_out[k][l] = state[k];
    }
  }

  // Lane l's F (into Fl), state (into state) and material row, from [component][lane] arrays.
  static FGS_FORCE_INLINE MaterialRow load_lane(const float* FGS_RESTRICT F_in, const float* FGS_RESTRICT state_in,
                                                const float* FGS_RESTRICT rows, int l, float Fl[9],
                                                float state[kMaxStateFields]) {
#pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) Fl[i] = F_in[i * kBatchLanes + l];
#pragma GCC unroll 9
    for (int k = 0; k < kMaxStateFields; ++k) state[k] = state_in[k * kBatchLanes + l];
    return MaterialRow{rows[kMatModel * kBatchLanes + l],
                       rows[kMatMu * kBatchLanes + l],
                       rows[kMatLambda * kBatchLanes + l],
                       rows[kMatBulk * kBatchLanes + l],
                       {rows[kMatParameter * kBatchLanes + l], rows[(kMatParameter + 1) * kBatchLanes + l],
                        rows[(kMatParameter + 2) * kBatchLanes + l]}};
  }

  // The eigen path (constitutive_stress_eig, then projected_deformation) on every lane; arrays are
  // [component][lane]. Two vectorised loops: the stress half on every lane, then F_E =
  // projected_deformation only if some lane was projected (most batches keep F: no exp needed).
  template <class Laws>
  static void eigen_lanes(const float* FGS_RESTRICT F_in, const float* FGS_RESTRICT state_in,
                          const float* FGS_RESTRICT rows, float* FGS_RESTRICT F_E,
                          float* FGS_RESTRICT state_new, float* FGS_RESTRICT tau_out,
                          float* FGS_RESTRICT dissipated, int32_t* FGS_RESTRICT ok) {
    double Q[9][kBatchLanes], log_stretch[3][kBatchLanes];
    float projected[kBatchLanes];
    // `#pragma omp simd` would turn the callee's by-reference locals into per-lane arrays before
    // inlining and then fail to vectorise; the plain vectoriser after inlining does not.
#pragma GCC ivdep
    for (int l = 0; l < kBatchLanes; ++l) {
      float Fl[9], tl[9], state[kMaxStateFields];
      const MaterialRow m = load_lane(F_in, state_in, rows, l, Fl, state);
      EigProjection proj;
      float taken;
      ok[l] = constitutive_stress_eig<Laws>(m, Fl, state, tl, &proj, &taken) ? 1 : 0;
      dissipated[l] = taken;
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) {
        tau_out[i * kBatchLanes + l] = tl[i];
        Q[i][l] = proj.Q[i];
      }
#pragma GCC unroll 9
      for (int i = 0; i < 3; ++i) log_stretch[i][l] = proj.log_stretch[i];
      projected[l] = proj.projected;
#pragma GCC unroll 9
      for (int k = 0; k < kMaxStateFields; ++k) state_new[k * kBatchLanes + l] = state[k];
    }
    float any_projected = 0.f;
    for (int l = 0; l < kBatchLanes; ++l) any_projected += projected[l];
    if (any_projected == 0.f) {
      for (int k = 0; k < 9 * kBatchLanes; ++k) F_E[k] = F_in[k];
      return;
    }
#pragma GCC ivdep
    for (int l = 0; l < kBatchLanes; ++l) {
      EigProjection proj;
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) proj.Q[i] = Q[i][l];
#pragma GCC unroll 9
      for (int i = 0; i < 3; ++i) proj.log_stretch[i] = log_stretch[i][l];
      proj.projected = projected[l];
      float Fl[9], Fo[9];
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) Fl[i] = F_in[i * kBatchLanes + l];
      projected_deformation(proj, Fl, Fo);
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) F_E[i * kBatchLanes + l] = Fo[i];
    }
  }

  // constitutive_small_strain on every lane: small[l] = 1 where it applies, and there F_out,
  // state_out and tau hold the result (and the update dissipated nothing). The other lanes'
  // outputs are meaningless.
  void run_small_strain(int32_t small[kBatchLanes]) {
    with_laws([&](auto laws) {
      FlushDenormals guard;
      small_strain_lanes<decltype(laws)>(&F[0][0], &state_in[0][0], &row[0][0], &F_out[0][0], &state_out[0][0],
                                         &tau[0][0], small);
    });
    for (int l = 0; l < kBatchLanes; ++l) dissipated[l] = 0.f;
  }

  template <class Laws>
  static void small_strain_lanes(const float* FGS_RESTRICT F_in, const float* FGS_RESTRICT state_in,
                                 const float* FGS_RESTRICT rows, float* FGS_RESTRICT F_E,
                                 float* FGS_RESTRICT state_new, float* FGS_RESTRICT tau_out,
                                 int32_t* FGS_RESTRICT small) {
#pragma GCC ivdep
    for (int l = 0; l < kBatchLanes; ++l) {
      float Fl[9], Fo[9], tl[9], state[kMaxStateFields];
      const MaterialRow m = load_lane(F_in, state_in, rows, l, Fl, state);
      small[l] = constitutive_small_strain<Laws>(m, Fl, state, Fo, tl) ? 1 : 0;
#pragma GCC unroll 9
      for (int i = 0; i < 9; ++i) {
        tau_out[i * kBatchLanes + l] = tl[i];
        F_E[i * kBatchLanes + l] = Fo[i];
      }
#pragma GCC unroll 9
      for (int k = 0; k < kMaxStateFields; ++k) state_new[k * kBatchLanes + l] = state[k];
    }
  }

  // Lane l takes lane `from` of another batch's inputs.
  void set_from(int l, const ConstitutiveBatch& other, int from) {
    #pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) F[i][l] = other.F[i][from];
    #pragma GCC unroll 9
    for (int k = 0; k < kMaxStateFields; ++k) state_in[k][l] = other.state_in[k][from];
    #pragma GCC unroll 9
    for (int k = 0; k < kMatFields; ++k) row[k][l] = other.row[k][from];
  }

  void get(int l, float* F_E, float* state, float* tau_out, float* taken) const {
    #pragma GCC unroll 9
    for (int i = 0; i < 9; ++i) {
      F_E[i] = F_out[i][l];
      tau_out[i] = tau[i][l];
    }
    #pragma GCC unroll 9
    for (int k = 0; k < kMaxStateFields; ++k) state[k] = state_out[k][l];
    *taken = dissipated[l];
  }
};

// Runs a stream of particles through the constitutive update, two tiers deep: every particle
// first takes the series path (constitutive_small_strain, no eigen-decomposition), kBatchLanes
// at a time; those it rejects (isochoric strain beyond the series range, near the yield surface,
// inverted, ...) are queued and run kBatchLanes at a time through the full update
// (ConstitutiveBatch::run).
// Every lane computes only from its own inputs, so a particle's result does not depend on which
// particles share its batches (and so not on the number of threads).
//
// Results come back through store(id, F_E, state, tau, dissipated) (state: kMaxStateFields floats),
// in no particular order; call finish() after the last push(). dissipated: the energy per unit
// rest volume the update took.
class ConstitutiveStream {
 public:
  // state: the particle's row of the state block (stride floats).
  template <class Store>
  void push(long long id, const float F_trial[9], const float* state, int stride, const float* mat_row, Store&& store) {
    fresh_.set(n_fresh_, F_trial, state, stride, mat_row);
    fresh_id_[n_fresh_++] = id;
    if (n_fresh_ == kBatchLanes) run_fresh(store);
  }

  template <class Store>
  void finish(Store&& store) {
    if (n_fresh_ > 0) run_fresh(store);
    if (n_slow_ > 0) run_slow(store);
  }

 private:
  template <class Store>
  void run_fresh(Store& store) {
    fresh_.pad(n_fresh_);
    int32_t small[kBatchLanes];
    fresh_.run_small_strain(small);
    for (int l = 0; l < n_fresh_; ++l) {
      if (small[l]) {
        emit(fresh_, l, fresh_id_[l], store);
        continue;
      }
      slow_.set_from(n_slow_, fresh_, l);
      slow_id_[n_slow_++] = fresh_id_[l];
      if (n_slow_ == kBatchLanes) run_slow(store);
    }
    n_fresh_ = 0;
  }

  template <class Store>
  void run_slow(Store& store) {
    slow_.pad(n_slow_);
    slow_.run(n_slow_);
    for (int l = 0; l < n_slow_; ++l) emit(slow_, l, slow_id_[l], store);
    n_slow_ = 0;
  }

  template <class Store>
  static void emit(const ConstitutiveBatch& batch, int l, long long id, Store& store) {
    float F_E[9], state[kMaxStateFields], tau[9], taken;
    batch.get(l, F_E, state, tau, &taken);
    store(id, F_E, static_cast<const float*>(state), tau, taken);
  }

  ConstitutiveBatch fresh_, slow_;
  long long fresh_id_[kBatchLanes], slow_id_[kBatchLanes];
  int n_fresh_ = 0, n_slow_ = 0;
};

}  // namespace fgs
