// Framework-free interface of the Gaussian rasterizer kernels (docs/formulas.md §11). Raw pointers,
// row-major, float32. The binding (raster_bind.cpp) allocates every buffer and runs the
// phases in order:
//   1. preprocess: project each Gaussian, colour it, find its tile rectangle; writes the
//      number of tiles it touches, from which the binding builds slot offsets (an exclusive
//      prefix sum, N+1 entries). Gaussian i owns the gradient slots
//      [slot_offset[i], slot_offset[i+1]), one per touched tile.
//   2. bin: list the slots of every tile, sorted front to back by (camera depth, index).
//   3. render_forward: blend each tile's list per pixel; keeps per pixel the final
//      transmittance, how many list entries were processed and (global exclusive rule) which
//      exclusive Gaussian won.
//   4. render_backward: reverse traversal per pixel; each (Gaussian, tile) slot gets the sum
//      of its pixel gradients (no atomics, deterministic).
//   5. preprocess_backward: per Gaussian, sum its slots in a fixed order and chain the
//      gradients back to the inputs.
#pragma once
#include <cstdint>

#include "common/gaussian.h"

namespace fgs {
namespace raster {

// Which Gaussians may blend at a pixel besides the 3DGS rules (docs/formulas.md §11, exclusive Gaussians).
// * flags (global rule, a bool per Gaussian): of all Gaussians flagged 1, only the nearest one with
//   alpha >= 1/255 blends at a pixel.
// * next (group rule, paper §3.2.2: the lenses that replace one g_i): next[i] is the next
//   member of i's group in a ring (i itself for a group of one), -1 for Gaussians in no group;
//   of each group only the nearest member with alpha >= 1/255 blends at a pixel, members of
//   different groups blend as usual. Stateless: a member is skipped where an earlier member
//   of its group (in blending order, camera depth then index) has alpha >= 1/255.
// At most one of them is non-null.
struct ExclusiveRule {
  const uint8_t* flags = nullptr;
  const int32_t* next = nullptr;
  // Group rule, per camera: earlier_group_member (common/blend.h) of every Gaussian, filled by
  // group_earlier_cpu / _cuda after preprocess (the binding does it).
  const int32_t* earlier = nullptr;
};

// Per-Gaussian inputs. Exactly one of (scales, quats) / covariances and one of sh / colors
// is non-null; view_rotations may be null.
struct GaussianInputs {
  int64_t num = 0;
  const float* means = nullptr;           // (N, 3)
  const float* opacities = nullptr;       // (N,)
  const float* scales = nullptr;          // (N, 3), activated
  const float* quats = nullptr;           // (N, 4), w x y z, any norm
  const float* covariances = nullptr;     // (N, 3, 3)
  const float* sh = nullptr;              // (N, K, 3), K = (sh_degree + 1)²
  int sh_degree = 0;
  const float* colors = nullptr;          // (N, 3)
  ExclusiveRule exclusive;                // (N,) each; both null: no exclusive Gaussians
  const float* view_rotations = nullptr;  // (N, 3, 3): SH direction = Rᵀ dir
};

// Gradients on the inputs (same shapes; null = not wanted). means2d gets dL/d(pixel mean).
struct GaussianGrads {
  float* means = nullptr;
  float* opacities = nullptr;
  float* scales = nullptr;
  float* quats = nullptr;
  float* covariances = nullptr;
  float* sh = nullptr;
  float* colors = nullptr;
  float* view_rotations = nullptr;
  float* means2d = nullptr;
};

// Binning result (sizes: tile_start num_tiles+1, tile_slots / slot_gaussian total_slots).
struct TileBins {
  int tiles_x = 0, tiles_y = 0;
  const int32_t* tile_start = nullptr;
  const int32_t* tile_slots = nullptr;
  const int32_t* slot_gaussian = nullptr;
};

// Per-pixel state kept from the forward for the backward (each H*W).
struct PixelState {
  float* final_T = nullptr;
  int32_t* n_contrib = nullptr;         // list position after the last blended entry
  int32_t* exclusive_winner = nullptr;  // global rule: list position of the blended exclusive
                                        // one, or -1 (unused by the group rule)
};

HOST_DEVICE inline int tiles_along(int pixels) { return (pixels + kTileSize - 1) / kTileSize; }

// ---- CPU (OpenMP) ----------------------------------------------------------------------
void preprocess_cpu(const CameraParams& cam, const GaussianInputs& in, float* proj,
                    int32_t* rect, int32_t* radii, int32_t* tiles_touched);
// Exclusive prefix sum of tiles_touched into slot_offset (N+1); returns the total.
int64_t slot_offsets_cpu(int64_t num, const int32_t* tiles_touched, int64_t* slot_offset);
void bin_cpu(const CameraParams& cam, int64_t num, const float* proj, const int32_t* rect,
             const int64_t* slot_offset, int32_t* tile_start, int32_t* tile_slots,
             int32_t* slot_gaussian);
// earlier[i] = earlier_group_member(proj, next, i) for every Gaussian with next[i] >= 0.
void group_earlier_cpu(int64_t num, const float* proj, const int32_t* next, int32_t* earlier);
void render_forward_cpu(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                        const TileBins& bins, const float* background, float* rgb,
                        float* alpha, float* depth, const PixelState& state);
void render_backward_cpu(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                         const TileBins& bins, const float* background,
                         const PixelState& state, const float* grad_rgb,
                         const float* grad_alpha, const float* grad_depth, float* slot_grads);
void preprocess_backward_cpu(const CameraParams& cam, const GaussianInputs& in,
                             const float* proj, const int64_t* slot_offset,
                             const float* slot_grads, const GaussianGrads& grads);

// ---- CUDA (raw device pointers; stream is a cudaStream_t passed as void*) ---------------
#ifdef FGS_WITH_CUDA
void preprocess_cuda(const CameraParams& cam, const GaussianInputs& in, float* proj,
                     int32_t* rect, int32_t* radii, int32_t* tiles_touched, void* stream);
// Bytes of scratch the prefix sum / the sort need.
size_t slot_offsets_scratch_bytes_cuda(int64_t num);
size_t sort_scratch_bytes_cuda(int64_t total_slots);
// Writes slot_offset (N+1) on the device and returns the total (synchronises the stream).
int64_t slot_offsets_cuda(int64_t num, const int32_t* tiles_touched, int64_t* slot_offset,
                          void* scratch, size_t scratch_bytes, void* stream);
// keys/values: 2 × total_slots each (double buffers for the radix sort).
void bin_cuda(const CameraParams& cam, int64_t num, const float* proj, const int32_t* rect,
              const int64_t* slot_offset, int64_t total_slots, int32_t* tile_start,
              int32_t* tile_slots, int32_t* slot_gaussian, uint64_t* keys, int32_t* values,
              void* scratch, size_t scratch_bytes, void* stream);
void group_earlier_cuda(int64_t num, const float* proj, const int32_t* next, int32_t* earlier,
                        void* stream);
void render_forward_cuda(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                         const TileBins& bins, const float* background, float* rgb,
                         float* alpha, float* depth, const PixelState& state, void* stream);
void render_backward_cuda(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                          const TileBins& bins, const float* background,
                          const PixelState& state, const float* grad_rgb,
                          const float* grad_alpha, const float* grad_depth, float* slot_grads,
                          void* stream);
void preprocess_backward_cuda(const CameraParams& cam, const GaussianInputs& in,
                              const float* proj, const int64_t* slot_offset,
                              const float* slot_grads, const GaussianGrads& grads,
                              void* stream);
#endif

}  // namespace raster
}  // namespace fgs
