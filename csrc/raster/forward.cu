// CUDA forward of the Gaussian rasterizer; mirrors raster_cpu.cpp phase by phase with the
// same per-Gaussian (preprocess.h) and per-pixel (common/blend.h) math. Binning: one key
// (tile << 32 | depth bits) per (Gaussian, tile) slot, emitted in Gaussian order and sorted
// with a stable radix sort, so each tile's list is in (depth, index) order exactly like the
// CPU lists. Blending: one 16x16 thread block per tile, Gaussians staged through shared
// memory in batches of 256, a block stops once all its pixels are saturated.
#include <cub/cub.cuh>

#include "common/blend.h"
#include "raster/preprocess.h"
#include "raster/raster_kernels.h"

namespace fgs {
namespace raster {
namespace {

constexpr int kBlock = kTileSize * kTileSize;

__device__ inline uint32_t orderable_bits(float value) {
  const uint32_t bits = __float_as_uint(value);
  return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
}

__global__ void preprocess_kernel(CameraParams cam, GaussianInputs in, float* proj, int32_t* rect,
                                  int32_t* radii, int32_t* tiles_touched) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < in.num) preprocess_one(cam, in, i, proj, rect, radii, tiles_touched);
}

__global__ void widen_counts_kernel(int64_t num, const int32_t* counts, int64_t* wide) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < num) wide[i] = counts[i];
  if (i == num) wide[i] = 0;
}

__global__ void emit_keys_kernel(int64_t num, int tiles_x, const float* proj, const int32_t* rect,
                                 const int64_t* slot_offset, uint64_t* keys, int32_t* values,
                                 int32_t* slot_gaussian) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= num || slot_offset[i + 1] == slot_offset[i]) return;
  const uint64_t depth_bits = orderable_bits(proj[kProjStride * i + kDepth]);
  const int32_t* r = rect + 4 * i;
  int64_t slot = slot_offset[i];
  for (int ty = r[1]; ty <= r[3]; ++ty)
    for (int tx = r[0]; tx <= r[2]; ++tx, ++slot) {
      keys[slot] = ((uint64_t)(ty * tiles_x + tx) << 32) | depth_bits;
      values[slot] = (int32_t)slot;
      slot_gaussian[slot] = (int32_t)i;
    }
}

// tile_start[t] for t in (tile of entry k-1, tile of entry k]; k = total closes the list.
__global__ void tile_start_kernel(int64_t total, int num_tiles, const uint64_t* sorted_keys,
                                  int32_t* tile_start) {
  const int64_t k = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (k > total) return;
  const int prev = k == 0 ? -1 : (int)(sorted_keys[k - 1] >> 32);
  const int cur = k == total ? num_tiles : (int)(sorted_keys[k] >> 32);
  for (int t = prev + 1; t <= cur; ++t) tile_start[t] = (int32_t)k;
}

__global__ void __launch_bounds__(kBlock)
    render_forward_kernel(CameraParams cam, const float* proj, ExclusiveRule exclusive,
                          TileBins bins, float bg_r, float bg_g, float bg_b, float* rgb,
                          float* alpha, float* depth, PixelState state) {
  __shared__ float s_proj[kBlock * kProjStride];
  __shared__ int32_t s_excl[kBlock];  // 1: exclusive under the global rule, 2: in a group
  __shared__ int32_t s_gid[kBlock];
  const int tile = blockIdx.x;
  const int x = (tile % bins.tiles_x) * kTileSize + (int)(threadIdx.x % kTileSize);
  const int y = (tile / bins.tiles_x) * kTileSize + (int)(threadIdx.x / kTileSize);
  const bool inside = x < cam.width && y < cam.height;
  const float px = (float)x + 0.5f, py = (float)y + 0.5f;
  bool done = !inside, taken = false;
  float T = 1.f, acc_r = 0.f, acc_g = 0.f, acc_b = 0.f, acc_d = 0.f;
  int32_t n_contrib = 0, winner = -1;
  const int32_t begin = bins.tile_start[tile], end = bins.tile_start[tile + 1];
  for (int32_t batch = begin; batch < end; batch += kBlock) {
    if (__syncthreads_count(done) == kBlock) break;
    const int32_t k = batch + (int32_t)threadIdx.x;
    if (k < end) {
      const int32_t gid = bins.slot_gaussian[bins.tile_slots[k]];
      for (int f = 0; f < kProjStride; ++f)
        s_proj[threadIdx.x * kProjStride + f] = proj[(int64_t)kProjStride * gid + f];
      s_excl[threadIdx.x] = exclusive.flags ? (int32_t)exclusive.flags[gid]
                            : (exclusive.next && exclusive.next[gid] >= 0 ? 2 : 0);
      s_gid[threadIdx.x] = gid;
    }
    __syncthreads();
    const int count = min(kBlock, end - batch);
    for (int j = 0; j < count && !done; ++j) {
      const float* g = s_proj + j * kProjStride;
      const bool excl = s_excl[j] == 1;
      if (excl && taken) continue;  // one exclusive Gaussian per pixel: skip the others unseen
      float G;
      const float a = splat_alpha(g[kU], g[kV], g[kConicA], g[kConicB], g[kConicC], g[kOpacity],
                                  px, py, G);
      if (a < kAlphaMin) continue;
      if (s_excl[j] == 2 && earlier_group_member_blends(proj, exclusive.next, exclusive.earlier, s_gid[j], px, py))
        continue;  // an earlier member of its group shades this pixel
      const float test_T = T * (1.f - a);
      if (test_T < kTransmittanceMin) { done = true; continue; }
      const float w = a * T;
      acc_r += w * g[kRed]; acc_g += w * g[kGreen]; acc_b += w * g[kBlue]; acc_d += w * g[kDepth];
      T = test_T;
      const int32_t pos = batch - begin + j;
      n_contrib = pos + 1;
      if (excl) { taken = true; winner = pos; }
    }
  }
  if (!inside) return;
  const int64_t pix = (int64_t)y * cam.width + x;
  rgb[3 * pix] = acc_r + T * bg_r;
  rgb[3 * pix + 1] = acc_g + T * bg_g;
  rgb[3 * pix + 2] = acc_b + T * bg_b;
  alpha[pix] = 1.f - T;
  depth[pix] = acc_d;
  state.final_T[pix] = T;
  state.n_contrib[pix] = n_contrib;
  state.exclusive_winner[pix] = winner;
}

__global__ void group_earlier_kernel(int64_t num, const float* proj, const int32_t* next,
                                     int32_t* earlier) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < num)
    earlier[i] = next[i] >= 0 ? earlier_group_member(proj, next, (int32_t)i) : kNoEarlierMember;
}

inline unsigned blocks_for(int64_t n, int threads) { return (unsigned)((n + threads - 1) / threads); }

inline int bits_needed(int64_t value) {
  int bits = 1;
  while ((int64_t(1) << bits) <= value) ++bits;
  return bits;
}

}  // namespace

void preprocess_cuda(const CameraParams& cam, const GaussianInputs& in, float* proj, int32_t* rect,
                     int32_t* radii, int32_t* tiles_touched, void* stream) {
  if (in.num == 0) return;
  preprocess_kernel<<<blocks_for(in.num, 256), 256, 0, (cudaStream_t)stream>>>(
      cam, in, proj, rect, radii, tiles_touched);
}

size_t slot_offsets_scratch_bytes_cuda(int64_t num) {
  size_t temp = 0;
  cub::DeviceScan::ExclusiveSum(nullptr, temp, (const int64_t*)nullptr, (int64_t*)nullptr,
                                (int)(num + 1));
  // 256 bytes of alignment slack for the base, each part rounded up to 256 bytes.
  return 256 + ((temp + 255) / 256) * 256 + ((size_t)(num + 1) * sizeof(int64_t) + 255) / 256 * 256;
}

int64_t slot_offsets_cuda(int64_t num, const int32_t* tiles_touched, int64_t* slot_offset,
                          void* scratch, size_t scratch_bytes, void* stream) {
  const cudaStream_t s = (cudaStream_t)stream;
  // Scratch layout: the widened counts, then cub's temporary storage (256-byte aligned).
  char* base = (char*)(((uintptr_t)scratch + 255) / 256 * 256);
  int64_t* wide = (int64_t*)base;
  char* temp = base + ((size_t)(num + 1) * sizeof(int64_t) + 255) / 256 * 256;
  size_t temp_bytes = scratch_bytes - (size_t)(temp - (char*)scratch);
  widen_counts_kernel<<<blocks_for(num + 1, 256), 256, 0, s>>>(num, tiles_touched, wide);
  cub::DeviceScan::ExclusiveSum(temp, temp_bytes, wide, slot_offset, (int)(num + 1), s);
  int64_t total = 0;
  cudaMemcpyAsync(&total, slot_offset + num, sizeof(int64_t), cudaMemcpyDeviceToHost, s);
  cudaStreamSynchronize(s);
  return total;
}

size_t sort_scratch_bytes_cuda(int64_t total_slots) {
  size_t temp = 0;
  cub::DoubleBuffer<uint64_t> keys(nullptr, nullptr);
  cub::DoubleBuffer<int32_t> values(nullptr, nullptr);
  cub::DeviceRadixSort::SortPairs(nullptr, temp, keys, values, (int)total_slots);
  return temp;
}

void bin_cuda(const CameraParams& cam, int64_t num, const float* proj, const int32_t* rect,
              const int64_t* slot_offset, int64_t total_slots, int32_t* tile_start,
              int32_t* tile_slots, int32_t* slot_gaussian, uint64_t* keys, int32_t* values,
              void* scratch, size_t scratch_bytes, void* stream) {
  const cudaStream_t s = (cudaStream_t)stream;
  const int tiles_x = tiles_along(cam.width), tiles_y = tiles_along(cam.height);
  const int num_tiles = tiles_x * tiles_y;
  if (total_slots > 0) {
    emit_keys_kernel<<<blocks_for(num, 256), 256, 0, s>>>(num, tiles_x, proj, rect, slot_offset,
                                                          keys, values, slot_gaussian);
    cub::DoubleBuffer<uint64_t> key_buffer(keys, keys + total_slots);
    cub::DoubleBuffer<int32_t> value_buffer(values, values + total_slots);
    cub::DeviceRadixSort::SortPairs(scratch, scratch_bytes, key_buffer, value_buffer,
                                    (int)total_slots, 0, 32 + bits_needed(num_tiles), s);
    cudaMemcpyAsync(tile_slots, value_buffer.Current(), total_slots * sizeof(int32_t),
                    cudaMemcpyDeviceToDevice, s);
    tile_start_kernel<<<blocks_for(total_slots + 1, 256), 256, 0, s>>>(
        total_slots, num_tiles, key_buffer.Current(), tile_start);
  } else {
    tile_start_kernel<<<1, 1, 0, s>>>(0, num_tiles, keys, tile_start);
  }
}

void group_earlier_cuda(int64_t num, const float* proj, const int32_t* next, int32_t* earlier,
                        void* stream) {
  if (num == 0) return;
  group_earlier_kernel<<<blocks_for(num, 256), 256, 0, (cudaStream_t)stream>>>(num, proj, next,
                                                                              earlier);
}

void render_forward_cuda(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                         const TileBins& bins, const float* background, float* rgb, float* alpha,
                         float* depth, const PixelState& state, void* stream) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
  render_forward_kernel<<<num_tiles, kBlock, 0, (cudaStream_t)stream>>>(
      cam, proj, exclusive, bins, background[0], background[1], background[2], rgb, alpha, depth,
      state);
}

}  // namespace raster
}  // namespace fgs
