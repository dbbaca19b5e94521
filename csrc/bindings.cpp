// The one pybind11 module fracture_gs._C. Each subsystem registers its own functions
// (csrc/<subsystem>/*_bind.cpp) so that the kernels themselves stay free of torch headers.
#include <torch/extension.h>

#include "bound_error.h"
#include "mpm/material_bind.h"
#include "mpm/mpm_bind.h"
#include "raster/raster_bind.h"
#include "fracture/fracture_bind.h"
#include "spatial/spatial_bind.h"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {
bool built_with_cuda() {
#ifdef FGS_WITH_CUDA
  return true;
#else
  return false;
#endif
}
int openmp_max_threads() {
#ifdef _OPENMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}
}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "fracture_gs compiled kernels (C++/OpenMP and, when built, CUDA)";
  m.def("built_with_cuda", &built_with_cuda, "True if the CUDA kernels were compiled in");
  m.def("openmp_max_threads", &openmp_max_threads, "OpenMP threads the CPU kernels use");
  fgs::register_materials(m);
  fgs::register_mpm(m);
  fgs::register_raster(m);
  fgs::register_spatial(m);
  fgs::register_fracture(m);
  // A kernel's violated bound (csrc/bound_error.h) becomes fracture_gs._backend.KernelBoundError,
  // so that callers can tell it from a bug.
  pybind11::register_exception_translator([](std::exception_ptr error) {
    try {
      if (error) std::rethrow_exception(error);
    } catch (const fgs::KernelBoundError& bound) {
      const pybind11::object type = pybind11::module_::import("fracture_gs._backend").attr("KernelBoundError");
      PyErr_SetString(type.ptr(), bound.what());
    }
  });
}
