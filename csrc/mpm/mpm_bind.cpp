#include "mpm/mpm_bind.h"
namespace fgs {
void register_mpm(pybind11::module& m) {}
}
