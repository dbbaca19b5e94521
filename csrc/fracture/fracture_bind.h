// Registration of the per-frame Gaussian ops (deformation, FPGO lens ellipsoids) on fracture_gs._C.
#pragma once
#include <torch/extension.h>

namespace fgs {
void register_fracture(pybind11::module& m);
}  // namespace fgs
