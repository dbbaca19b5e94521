// GCC vector types of the CPU kernels (AVX where the machine has it, two SSE halves otherwise):
// a P2G node record of 8 floats and a 4-float lane for 3-vectors. CPU only (not for nvcc).
#pragma once

namespace fgs {

using Record = float __attribute__((vector_size(32)));
using Lane4 = float __attribute__((vector_size(16)));

}  // namespace fgs
