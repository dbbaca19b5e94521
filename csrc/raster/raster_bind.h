// Registration of the raster ops on the fracture_gs._C module.
#pragma once
#include <torch/extension.h>

namespace fgs {
void register_raster(pybind11::module& m);
}  // namespace fgs
