// Registration of the spatial ops (hash-grid neighbours, connected components) on fracture_gs._C.
#pragma once
#include <torch/extension.h>

namespace fgs {
void register_spatial(pybind11::module& m);
}  // namespace fgs
