// CUDA backward of the Gaussian rasterizer; mirrors render_backward_cpu /
// preprocess_backward_cpu with the same math headers. One 16x16 block per tile walks the
// tile's list in reverse (from the largest per-pixel contributor count); for every entry the
// pixel gradients are reduced inside the block in a fixed order (warp shuffles, then warps
// in order) and written to that (Gaussian, tile) slot: no float atomics, deterministic.
// A second kernel sums each Gaussian's slots in order and chains back to its inputs.
#include "common/blend.h"
#include "raster/preprocess.h"
#include "raster/raster_kernels.h"

namespace fgs {
namespace raster {
namespace {

constexpr int kBlock = kTileSize * kTileSize;
constexpr int kWarps = kBlock / 32;

__global__ void __launch_bounds__(kBlock)
    render_backward_kernel(CameraParams cam, const float* proj, ExclusiveRule exclusive,
                           TileBins bins, float bg_r, float bg_g, float bg_b, PixelState state,
                           const float* grad_rgb, const float* grad_alpha,
                           const float* grad_depth, float* slot_grads) {
  __shared__ float s_proj[kBlock * kProjStride];
  __shared__ int32_t s_excl[kBlock];  // 1: exclusive under the global rule, 2: in a group
  __shared__ int32_t s_gid[kBlock];
  __shared__ int32_t s_slot[kBlock];
  __shared__ float s_partial[kWarps][kSlotStride];
  __shared__ int32_t s_max_contrib;
  const int tile = blockIdx.x;
  const int x = (tile % bins.tiles_x) * kTileSize + (int)(threadIdx.x % kTileSize);
  const int y = (tile / bins.tiles_x) * kTileSize + (int)(threadIdx.x / kTileSize);
  const bool inside = x < cam.width && y < cam.height;
  const float px = (float)x + 0.5f, py = (float)y + 0.5f;
  const int lane = threadIdx.x % 32, warp = threadIdx.x / 32;
  float T = 1.f, later = 0.f, tail = 0.f, g_r = 0.f, g_g = 0.f, g_b = 0.f, g_d = 0.f;
  int32_t n_contrib = 0, winner = -1;
  if (inside) {
    const int64_t pix = (int64_t)y * cam.width + x;
    T = state.final_T[pix];
    g_r = grad_rgb[3 * pix]; g_g = grad_rgb[3 * pix + 1]; g_b = grad_rgb[3 * pix + 2];
    g_d = grad_depth[pix];
    tail = T * (bg_r * g_r + bg_g * g_g + bg_b * g_b - grad_alpha[pix]);
    n_contrib = state.n_contrib[pix];
    winner = state.exclusive_winner[pix];
  }
  if (threadIdx.x == 0) s_max_contrib = 0;
  __syncthreads();
  atomicMax(&s_max_contrib, n_contrib);  // integer max: order-independent
  __syncthreads();
  const int32_t max_contrib = s_max_contrib;
  const int32_t begin = bins.tile_start[tile];
  for (int32_t batch_end = max_contrib; batch_end > 0; batch_end -= kBlock) {
    const int count = min(kBlock, (int)batch_end);
    __syncthreads();
    if ((int)threadIdx.x < count) {
      const int32_t pos = batch_end - 1 - (int32_t)threadIdx.x;
      const int32_t slot = bins.tile_slots[begin + pos];
      const int32_t gid = bins.slot_gaussian[slot];
      for (int f = 0; f < kProjStride; ++f)
        s_proj[threadIdx.x * kProjStride + f] = proj[(int64_t)kProjStride * gid + f];
      s_excl[threadIdx.x] = exclusive.flags ? (int32_t)exclusive.flags[gid]
                            : (exclusive.next && exclusive.next[gid] >= 0 ? 2 : 0);
      s_gid[threadIdx.x] = gid;
      s_slot[threadIdx.x] = slot;
    }
    __syncthreads();
    for (int j = 0; j < count; ++j) {
      const int32_t pos = batch_end - 1 - j;
      const float* g = s_proj + j * kProjStride;
      float contrib[kSlotStride];
      for (int f = 0; f < kSlotStride; ++f) contrib[f] = 0.f;
      float G = 0.f;
      const float a = (pos < n_contrib)
                          ? splat_alpha(g[kU], g[kV], g[kConicA], g[kConicB], g[kConicC],
                                        g[kOpacity], px, py, G)
                          : 0.f;
      const bool active =
          (pos < n_contrib) && (a >= kAlphaMin) &&
          (s_excl[j] == 0 || (s_excl[j] == 1 && winner == pos) ||
           (s_excl[j] == 2 && !earlier_group_member_blends(proj, exclusive.next, exclusive.earlier, s_gid[j], px, py)));
      if (active) {
        const float one_minus = 1.f - a;
        const float T_before = T / one_minus;
        const float w = a * T_before;
        const float shade = g[kRed] * g_r + g[kGreen] * g_g + g[kBlue] * g_b + g[kDepth] * g_d;
        const float g_alpha = T_before * shade - (later + tail) / one_minus;
        splat_alpha_backward(g[kU], g[kV], g[kConicA], g[kConicB], g[kConicC], g[kOpacity], px,
                             py, G, g_alpha, contrib);
        contrib[kGradRed] = w * g_r; contrib[kGradGreen] = w * g_g;
        contrib[kGradBlue] = w * g_b; contrib[kGradDepth] = w * g_d;
        later += w * shade;
        T = T_before;
      }
      if (!__syncthreads_or(active)) continue;  // nothing to write: the slot stays zero
      for (int f = 0; f < kSlotStride; ++f) {
        float v = contrib[f];
        for (int offset = 16; offset > 0; offset /= 2) v += __shfl_down_sync(0xffffffffu, v, offset);
        if (lane == 0) s_partial[warp][f] = v;
      }
      __syncthreads();
      if ((int)threadIdx.x < kSlotStride) {
        float total = 0.f;
        for (int w = 0; w < kWarps; ++w) total += s_partial[w][threadIdx.x];
        slot_grads[(int64_t)kSlotStride * s_slot[j] + threadIdx.x] = total;
      }
    }
  }
}

__global__ void preprocess_backward_kernel(CameraParams cam, GaussianInputs in,
                                           const int64_t* slot_offset, const float* slot_grads,
                                           GaussianGrads grads) {
  const int64_t i = (int64_t)blockIdx.x * blockDim.x + threadIdx.x;
  if (i < in.num) preprocess_backward_one(cam, in, i, slot_offset, slot_grads, grads);
}

}  // namespace

void render_backward_cuda(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                          const TileBins& bins, const float* background, const PixelState& state,
                          const float* grad_rgb, const float* grad_alpha, const float* grad_depth,
                          float* slot_grads, void* stream) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
  render_backward_kernel<<<num_tiles, kBlock, 0, (cudaStream_t)stream>>>(
      cam, proj, exclusive, bins, background[0], background[1], background[2], state, grad_rgb,
      grad_alpha, grad_depth, slot_grads);
}

void preprocess_backward_cuda(const CameraParams& cam, const GaussianInputs& in, const float* proj,
                              const int64_t* slot_offset, const float* slot_grads,
                              const GaussianGrads& grads, void* stream) {
  (void)proj;
  if (in.num == 0) return;
  preprocess_backward_kernel<<<(unsigned)((in.num + 255) / 256), 256, 0, (cudaStream_t)stream>>>(
      cam, in, slot_offset, slot_grads, grads);
}

}  // namespace raster
}  // namespace fgs
