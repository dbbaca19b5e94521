// CUDA loops of the per-frame Gaussian kernels (math in fracture_one.h), one thread per row.
#include <cuda_runtime.h>

#include "fracture/fracture_one.h"

namespace fgs {
namespace fracture {
namespace {

constexpr int kThreads = 256;

__global__ void deform_kernel(DeformInputs in, DeformOutputs out) {
  const int64_t g = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (g < in.num_gaussians) deform_one(in, out, g);
}

__global__ void lens_kernel(LensInputs in, LensOutputs out) {
  const int64_t p = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (p < in.num_pairs) lens_one(in, out, p);
}

}  // namespace

void deform_gaussians_cuda(const DeformInputs& in, const DeformOutputs& out, void* stream) {
  if (in.num_gaussians == 0) return;
  const int blocks = (int)((in.num_gaussians + kThreads - 1) / kThreads);
  deform_kernel<<<blocks, kThreads, 0, (cudaStream_t)stream>>>(in, out);
}

void lens_ellipsoids_cuda(const LensInputs& in, const LensOutputs& out, void* stream) {
  if (in.num_pairs == 0) return;
  const int blocks = (int)((in.num_pairs + kThreads - 1) / kThreads);
  lens_kernel<<<blocks, kThreads, 0, (cudaStream_t)stream>>>(in, out);
}

}  // namespace fracture
}  // namespace fgs
