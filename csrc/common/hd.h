// Host/device qualifiers shared by every math header: the same inline function compiles
// into the C++ (OpenMP) kernels and into the CUDA kernels.
#pragma once

#if defined(__CUDACC__)
#define HOST_DEVICE __host__ __device__
#define FGS_RESTRICT __restrict__
#define FGS_FORCE_INLINE __forceinline__
#define FGS_UNROLL _Pragma("unroll")
#else
#define HOST_DEVICE
#define FGS_RESTRICT __restrict__
#define FGS_FORCE_INLINE __attribute__((always_inline)) inline
#define FGS_UNROLL _Pragma("GCC unroll 32")
#endif
// FGS_FORCE_INLINE: for functions called from loops that must vectorise; the vectoriser only
// sees through calls that are inlined. FGS_UNROLL: unroll the next loop fully (short fixed trip
// counts over constant tables, so that no loop is left inside vectorised code).
