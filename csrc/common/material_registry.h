// The material models the kernels know, and the dispatch on a table row's model code. Adding a
// model: write its header in csrc/common/materials/ (the interface: csrc/common/material_law.h)
// and add it to MaterialModels below; its Python class is listed in fracture_gs/materials/__init__.py.
#pragma once
#include "common/material_law.h"
#include "common/materials/brittle.h"
#include "common/materials/elastic.h"
#include "common/materials/nacc.h"
#include "common/materials/von_mises.h"

namespace fgs {

template <class... Models>
struct ModelList {
  static constexpr int kCount = sizeof...(Models);
  static constexpr int kMaxStateFields = [] {
    int most = 0;
    ((most = Models::kStateFields > most ? Models::kStateFields : most), ...);
    return most;
  }();
  static_assert(((Models::kStateFields >= 1 && Models::kStateFields <= kStateCapacity) && ...),
                "a model has 1 to kStateCapacity state fields");

  // True if the row's model is one of these.
  HOST_DEVICE FGS_FORCE_INLINE static bool known(const MaterialRow& m) {
    return ((m.model == (float)Models::kCode) | ...);
  }

  // The row's law on the invariants. Every model's law is evaluated and the row's result selected
  // (no branch: the CPU paths vectorise over particles of mixed models). An unknown model keeps
  // the state with the linear stress; callers check known(). State fields a model does not own
  // keep their values.
  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow& m, const float* state,
                                                       const StrainInvariants& s) {
    LawResult out = elastic_result<kMaxStateFields>(state, s);
    (select<Models>(m, Models::update(m, state, s), out), ...);
    return out;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double principal_stress(const MaterialRow& m, const LawResult& r, double dev_i,
                                                              double e) {
    double out = 0.0;
    ((out = m.model == (float)Models::kCode ? Models::principal_stress(m, r, dev_i, e) : out), ...);
    return out;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double dissipated(const MaterialRow& m, const float* state, const LawResult& r,
                                                        const double dev[3], double e) {
    double out = 0.0;
    ((out = m.model == (float)Models::kCode ? Models::dissipated(m, state, r, dev, e) : out), ...);
    return out;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double energy(const MaterialRow& m, const float* state, const double eps[3],
                                                    double e) {
    double out = 0.0;
    ((out = m.model == (float)Models::kCode ? Models::energy(m, state, eps, e) : out), ...);
    return out;
  }

  // Calls visit(Model{}) once per model, in list order (the bindings describe them).
  template <class Visit>
  static constexpr void for_each(Visit&& visit) {
    (visit(Models{}), ...);
  }

  // Calls visit(Model{}) for the model whose code is `code`; returns false if none has it.
  template <class Visit>
  static bool visit_code(float code, Visit&& visit) {
    bool found = false;
    ((!found && code == (float)Models::kCode ? (visit(Models{}), found = true) : false), ...);
    return found;
  }

 private:
  template <class Model>
  HOST_DEVICE FGS_FORCE_INLINE static void select(const MaterialRow& m, const LawResult& r, LawResult& out) {
    const bool mine = m.model == (float)Model::kCode;
    out.dev_scale = mine ? r.dev_scale : out.dev_scale;
    out.e_out = mine ? r.e_out : out.e_out;
    out.shear = mine ? r.shear : out.shear;
    out.volume = mine ? r.volume : out.volume;
    out.decided = mine ? r.decided : out.decided;
    out.projected = mine ? r.projected : out.projected;
    FGS_UNROLL
    for (int k = 0; k < Model::kStateFields; ++k) out.state[k] = mine ? r.state[k] : out.state[k];
  }
};

// The models, one line each; a model's kCode is its row of this list.
using MaterialModels = ModelList<
    ElasticModel,
    NaccModel,
    BrittleModel,
    VonMisesModel>;

constexpr int kMaxStateFields = MaterialModels::kMaxStateFields;
static_assert([] {
  int index = 0;
  bool ordered = true;
  MaterialModels::for_each([&](auto model) { ordered = ordered && decltype(model)::kCode == index++; });
  return ordered;
}(), "a model's kCode is its position in MaterialModels");

// The same interface as MaterialModels for rows that all have one model: the law of that model alone,
// no selection (the CPU paths run a batch whose lanes share a model this way). The state fields the
// model does not own keep their values, as with MaterialModels::update.
template <class Model>
struct OneModel {
  HOST_DEVICE FGS_FORCE_INLINE static bool known(const MaterialRow& m) { return m.model == (float)Model::kCode; }

  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow& m, const float* state,
                                                       const StrainInvariants& s) {
    LawResult r = Model::update(m, state, s);
    FGS_UNROLL
    for (int k = Model::kStateFields; k < kMaxStateFields; ++k) r.state[k] = state[k];
    return r;
  }

  HOST_DEVICE FGS_FORCE_INLINE static double principal_stress(const MaterialRow& m, const LawResult& r, double dev_i,
                                                              double e) {
    return Model::principal_stress(m, r, dev_i, e);
  }

  HOST_DEVICE FGS_FORCE_INLINE static double dissipated(const MaterialRow& m, const float* state, const LawResult& r,
                                                        const double dev[3], double e) {
    return Model::dissipated(m, state, r, dev, e);
  }
};

}  // namespace fgs
