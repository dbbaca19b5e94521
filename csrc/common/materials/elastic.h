// model: elastic (fracture_gs/materials/elastic.py): St. Venant-Kirchhoff on the Hencky strain, no
// plasticity, never fractured. Its state field is carried and never changes.
#pragma once
#include "common/material_law.h"

namespace fgs {

struct ElasticModel : HenckyLaw {
  static constexpr int kCode = 0;
  static constexpr const char* kName = "elastic";
  static constexpr const char* kParameters[kMatParameters] = {"", "", ""};
  static constexpr int kStateFields = 1;
  static constexpr const char* kState[kStateFields] = {"alpha"};

  HOST_DEVICE FGS_FORCE_INLINE static LawResult update(const MaterialRow&, const float* state,
                                                       const StrainInvariants& s) {
    return elastic_result<kStateFields>(state, s);
  }
};

}  // namespace fgs
