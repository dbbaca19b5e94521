// The error a compiled kernel raises when its input breaks a bound the kernel is built for (an
// index outside the buffer it indexes, a particle outside the cell it was binned into, more
// entries than an int32 list can count). Host code only: kernels detect the violation, skip the
// access that would leave their buffers, and their launcher or binding throws this once the
// parallel loop is over. bindings.cpp turns it into fracture_gs._backend.KernelBoundError (a
// RuntimeError), which simulate.py reports as one line with exit status 1.
#pragma once
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace fgs {

class KernelBoundError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Throws KernelBoundError with the parts streamed into one message.
template <class... Parts>
[[noreturn]] void throw_bound_error(const Parts&... parts) {
  std::ostringstream message;
  (message << ... << parts);
  throw KernelBoundError(message.str());
}

// Lists and counts the kernels index with int32.
constexpr int64_t kMaxInt32Count = std::numeric_limits<int32_t>::max();

// Position of the first of the n entries of v outside [0, limit), or -1 (one min / max pass,
// then a search only where it failed).
inline int64_t first_outside(const int32_t* v, int64_t n, int64_t limit) {
  if (n == 0) return -1;
  int32_t lo = v[0], hi = v[0];
  for (int64_t i = 1; i < n; ++i) {
    lo = v[i] < lo ? v[i] : lo;
    hi = v[i] > hi ? v[i] : hi;
  }
  if (lo >= 0 && hi < limit) return -1;
  for (int64_t i = 0; i < n; ++i)
    if (v[i] < 0 || v[i] >= limit) return i;
  return -1;
}

}  // namespace fgs
