// Registration of the material ops (constitutive_update, elastic_energy, svd3_batch) on
// the fracture_gs._C module.
#pragma once
#include <torch/extension.h>

namespace fgs {
void register_materials(pybind11::module& m);
}  // namespace fgs
