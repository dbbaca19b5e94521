// Host/device qualifiers shared by every math header: the same inline function compiles
// into the C++ (OpenMP) kernels and into the CUDA kernels.
#pragma once

#if defined(__CUDACC__)
#define HOST_DEVICE __host__ __device__
#define FGS_RESTRICT __restrict__
#define FGS_FORCE_INLINE __forceinline__
#else
#define HOST_DEVICE
#define FGS_RESTRICT __restrict__
#define FGS_FORCE_INLINE __attribute__((always_inline)) inline
#endif
// FGS_FORCE_INLINE: for functions called from loops that must vectorise; the vectoriser only
// sees through calls that are inlined.
