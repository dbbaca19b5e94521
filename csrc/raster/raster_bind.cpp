#include "raster/raster_bind.h"
namespace fgs {
void register_raster(pybind11::module& m) {}
}
