// Branch-free exp (float32 and float64), log1p and sinh (float64) for the vectorised
// constitutive update (csrc/common/hencky_eig.h). Written with selects instead of branches and with no calls into
// libm (other than sqrt/floor, which compile to single instructions), so that a
// `#pragma omp simd` loop around them becomes AVX/AVX-512 code; on the GPU they are ordinary
// device functions. Accuracy: a few ulp over the ranges the MPM update uses (documented per
// function); the tests compare the update they feed against a float64 twin.
#pragma once
#include <cmath>
#include <cstdint>

#include "common/hd.h"

namespace fgs {
namespace fast_math {

HOST_DEVICE FGS_FORCE_INLINE int32_t float_bits(float x) {
#if defined(__CUDA_ARCH__)
  return __float_as_int(x);
#else
  return __builtin_bit_cast(int32_t, x);
#endif
}

HOST_DEVICE FGS_FORCE_INLINE float bits_float(int32_t i) {
#if defined(__CUDA_ARCH__)
  return __int_as_float(i);
#else
  return __builtin_bit_cast(float, i);
#endif
}

// min / max as selects: fminf/fmaxf have NaN rules that keep GCC from vectorising them.
template <class T>
HOST_DEVICE FGS_FORCE_INLINE T min_of(T a, T b) {
  return a < b ? a : b;
}
template <class T>
HOST_DEVICE FGS_FORCE_INLINE T max_of(T a, T b) {
  return a > b ? a : b;
}
template <class T>
HOST_DEVICE FGS_FORCE_INLINE T abs_of(T a) {
  return a < T(0) ? -a : a;
}

// c[0] + x (c[1] + x (c[2] + ... + x c[N-1])), by Horner. T may also be a GCC vector type:
// the coefficients then apply to every lane.
template <class T, class C, int N>
HOST_DEVICE FGS_FORCE_INLINE T polynomial(T x, const C (&c)[N]) {
  T p = T{} + c[N - 1];
  FGS_UNROLL
  for (int k = N - 2; k >= 0; --k) p = p * x + c[k];
  return p;
}

constexpr float kLn2Hi = 0.693145751953125f;       // ln 2 with its low mantissa bits zero
constexpr float kLn2Lo = 1.428606820309417232e-6f;  // ln 2 - kLn2Hi

// e^x for x in [-87, 88] (clamped outside): x = k ln2 + r, |r| <= ln2 / 2, degree-7 Taylor
// polynomial of e^r (truncation < 6e-9 relative), times 2^k built from the exponent bits.
HOST_DEVICE FGS_FORCE_INLINE float exp_f(float x) {
  x = min_of(max_of(x, -87.f), 88.f);
  const float k = floorf(x * 1.44269504088896341f + 0.5f);
  const float r = (x - k * kLn2Hi) - k * kLn2Lo;
  const float taylor[8] = {1.f, 1.f, 0.5f, 1.f / 6.f, 1.f / 24.f, 1.f / 120.f, 1.f / 720.f, 1.f / 5040.f};
  return polynomial(r, taylor) * bits_float((static_cast<int32_t>(k) + 127) << 23);
}

// ---- double precision (2^k comes from the float exponent bits, so the vectoriser never needs
// int64 <-> double conversions, which AVX2 lacks) ----

constexpr double kLn2HiD = 6.93147180369123816490e-01;  // ln 2, high part (fdlibm)
constexpr double kLn2LoD = 1.90821492927058770002e-10;  // ln 2 - kLn2HiD

// 2^k for an integral k in [-126, 127], exactly.
HOST_DEVICE FGS_FORCE_INLINE double exp2_integer_d(double k) {
  return (double)bits_float((static_cast<int32_t>(k) + 127) << 23);
}

// e^x for x in [-87, 87] (clamped outside), ~1 ulp: degree-12 Taylor polynomial of e^r,
// |r| <= ln2 / 2 (truncation < 2e-16 relative).
HOST_DEVICE FGS_FORCE_INLINE double exp_d(double x) {
  x = min_of(max_of(x, -87.0), 87.0);
  const double k = floor(x * 1.4426950408889634074 + 0.5);
  const double r = (x - k * kLn2HiD) - k * kLn2LoD;
  const double taylor[13] = {1.0,           1.0,            0.5,           1.0 / 6.0,       1.0 / 24.0,
                             1.0 / 120.0,   1.0 / 720.0,    1.0 / 5040.0,  1.0 / 40320.0,   1.0 / 362880.0,
                             1.0 / 3628800.0, 1.0 / 39916800.0, 1.0 / 479001600.0};
  return polynomial(r, taylor) * exp2_integer_d(k);
}

// ln u for u in [1e-37, 1e38]: k from the exponent of (float)u, m = u 2^-k in ~[0.707, 1.414],
// ln m = 2 atanh(s) to s^21 (truncation < 1e-16 relative).
HOST_DEVICE FGS_FORCE_INLINE double log_d(double u) {
  const int32_t bits = float_bits((float)u);
  int32_t k = ((bits >> 23) & 0xff) - 127;
  const float mf = bits_float((bits & 0x007fffff) | 0x3f800000);  // [1, 2)
  k = mf > 1.41421356237f ? k + 1 : k;
  const double kd = (double)k;
  const double m = u * exp2_integer_d(-kd);
  const double s = (m - 1.0) / (m + 1.0);
  const double s2 = s * s;
  const double atanh_series[11] = {1.0,        1.0 / 3.0,  1.0 / 5.0,  1.0 / 7.0,  1.0 / 9.0, 1.0 / 11.0,
                                   1.0 / 13.0, 1.0 / 15.0, 1.0 / 17.0, 1.0 / 19.0, 1.0 / 21.0};
  const double series = polynomial(s2, atanh_series);
  return kd * kLn2HiD + (kd * kLn2LoD + 2.0 * s * series);
}

// ln(1 + x) for x in (-1 + 1e-37, 1e38), accurate to a few ulp of the result even for tiny x:
// u = 1 + x is rounded, and ln(u) x / (u - 1) cancels that rounding (Goldberg's trick).
HOST_DEVICE FGS_FORCE_INLINE double log1p_d(double x) {
  const double u = 1.0 + x;
  const double d = u - 1.0;
  const double safe_d = d != 0.0 ? d : 1.0;
  return d != 0.0 ? log_d(u) * (x / safe_d) : x;
}

// sinh x for x in [0, 87]: Taylor series to x^15 below 0.5, (e^x - e^-x) / 2 above.
HOST_DEVICE FGS_FORCE_INLINE double sinh_nonnegative_d(double x) {
  const double x2 = x * x;
  const double taylor[8] = {1.0,            1.0 / 6.0,         1.0 / 120.0,        1.0 / 5040.0,
                            1.0 / 362880.0, 1.0 / 39916800.0, 1.0 / 6227020800.0, 1.0 / 1307674368000.0};
  const double series = polynomial(x2, taylor);
  const double e = exp_d(x);
  return x < 0.5 ? x * series : 0.5 * (e - 1.0 / e);
}

}  // namespace fast_math
}  // namespace fgs
