// Helpers for the torch binding files only (kernels never include torch).
#pragma once
#ifdef FGS_WITH_CUDA
// c10's stream header, not ATen/cuda/CUDAContext.h: the latter pulls in cusparse.h, which a
// CUDA toolkit install does not always provide.
#include <c10/cuda/CUDAStream.h>

namespace fgs {
// The current torch CUDA stream as the opaque pointer the CUDA launchers take.
inline void* current_cuda_stream() { return static_cast<void*>(c10::cuda::getCurrentCUDAStream().stream()); }
}  // namespace fgs
#endif
