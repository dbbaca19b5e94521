// Registration of the mpm ops on the fracture_gs._C module.
#pragma once
#include <torch/extension.h>

namespace fgs {
void register_mpm(pybind11::module& m);
}  // namespace fgs
