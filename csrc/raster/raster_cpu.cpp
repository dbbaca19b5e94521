// CPU (OpenMP) kernels of the Gaussian rasterizer. Per-Gaussian work is a parallel loop over
// Gaussians; binning sorts the visible Gaussians once by (depth, index) and fills the tile
// lists in that order, so every tile list is sorted front to back. Blending runs one tile per
// task (dynamic schedule): the tile's Gaussians are gathered into a structure-of-arrays list,
// each 8x8 quarter of the tile keeps the entries whose support box reaches it, and every
// pixel walks that list front to back, computing alphas 8 entries at a time (SIMD) and
// blending sequentially until it saturates (like one CUDA thread). The backward walks each
// pixel's list in reverse and sums the pixel gradients of each list entry in a tile-local
// buffer, written to that entry's (Gaussian, tile) slot: no atomics, and the same bits for
// any thread count.

// The blending loops compute alphas for several Gaussians at once; GCC only vectorises
// their selects (min, comparisons) when it may assume FP operations do not trap. No code
// here relies on floating-point exception flags.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("no-trapping-math")
#endif
#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "common/blend.h"
#include "raster/preprocess.h"
#include "raster/raster_kernels.h"

namespace fgs {
namespace raster {
namespace {

// Below these sizes the OpenMP fork/join (and thread wake-up on a busy machine) costs more
// than the work, so the loops run on the calling thread.
constexpr int64_t kParallelGaussians = 8192;
constexpr int kParallelTiles = 8;

// Order-preserving map of a float to an unsigned integer (for sort keys).
inline uint32_t orderable_bits(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
}

struct TileGeometry {
  int x0, y0, width, height;
};

inline TileGeometry tile_geometry(const CameraParams& cam, int tiles_x, int tile) {
  TileGeometry t;
  t.x0 = (tile % tiles_x) * kTileSize;
  t.y0 = (tile / tiles_x) * kTileSize;
  t.width = std::min(kTileSize, cam.width - t.x0);
  t.height = std::min(kTileSize, cam.height - t.y0);
  return t;
}

}  // namespace

void preprocess_cpu(const CameraParams& cam, const GaussianInputs& in, float* proj, int32_t* rect,
                    int32_t* radii, int32_t* tiles_touched) {
#pragma omp parallel for schedule(static) if (in.num >= kParallelGaussians)
  for (int64_t i = 0; i < in.num; ++i) preprocess_one(cam, in, i, proj, rect, radii, tiles_touched);
}

int64_t slot_offsets_cpu(int64_t num, const int32_t* tiles_touched, int64_t* slot_offset) {
  int64_t total = 0;
  for (int64_t i = 0; i < num; ++i) {
    slot_offset[i] = total;
    total += tiles_touched[i];
  }
  slot_offset[num] = total;
  return total;
}

void bin_cpu(const CameraParams& cam, int64_t num, const float* proj, const int32_t* rect,
             const int64_t* slot_offset, int32_t* tile_start, int32_t* tile_slots,
             int32_t* slot_gaussian) {
  const int tiles_x = tiles_along(cam.width), tiles_y = tiles_along(cam.height);
  const int num_tiles = tiles_x * tiles_y;
  std::vector<uint64_t> order;
  order.reserve(num);
  for (int64_t i = 0; i < num; ++i)
    if (slot_offset[i + 1] > slot_offset[i])
      order.push_back(((uint64_t)orderable_bits(proj[kProjStride * i + kDepth]) << 32) | (uint64_t)i);
  std::sort(order.begin(), order.end());  // by depth, ties by index
  std::vector<int64_t> cursor(num_tiles + 1, 0);
  for (uint64_t key : order) {
    const int32_t* r = rect + 4 * (key & 0xffffffffu);
    for (int ty = r[1]; ty <= r[3]; ++ty)
      for (int tx = r[0]; tx <= r[2]; ++tx) ++cursor[ty * tiles_x + tx + 1];
  }
  for (int t = 0; t < num_tiles; ++t) cursor[t + 1] += cursor[t];
  for (int t = 0; t <= num_tiles; ++t) tile_start[t] = (int32_t)cursor[t];
  for (uint64_t key : order) {
    const int64_t i = (int64_t)(key & 0xffffffffu);
    const int32_t* r = rect + 4 * i;
    int64_t slot = slot_offset[i];
    for (int ty = r[1]; ty <= r[3]; ++ty)
      for (int tx = r[0]; tx <= r[2]; ++tx, ++slot) {
        tile_slots[cursor[ty * tiles_x + tx]++] = (int32_t)slot;
        slot_gaussian[slot] = (int32_t)i;
      }
  }
}

namespace {

constexpr int kBatch = 8;  // alphas are computed for this many list entries at once (SIMD)

constexpr int kQuad = kTileSize / 2;  // pixels are processed in 8x8 quarters of a tile

// Gaussians in list order as structure-of-arrays, padded to a multiple of kBatch with fully
// transparent entries; pos is the position in the tile's list.
struct TileList {
  std::vector<float> u, v, A, B, C, opacity, red, green, blue, depth, ex, ey;
  std::vector<int32_t> exclusive, pos;
  int32_t size = 0;

  // All Gaussians of a tile.
  void gather(const TileBins& bins, int tile, const float* proj, const uint8_t* excl) {
    const int32_t begin = bins.tile_start[tile];
    reset(bins.tile_start[tile + 1] - begin);
    constexpr int32_t kAhead = 8;  // two-stage software prefetch of the random-order reads
    for (int32_t k = 0; k < size; ++k) {
      if (k + 2 * kAhead < size) __builtin_prefetch(bins.slot_gaussian + bins.tile_slots[begin + k + 2 * kAhead]);
      if (k + kAhead < size)
        __builtin_prefetch(proj + (int64_t)kProjStride * bins.slot_gaussian[bins.tile_slots[begin + k + kAhead]]);
      const int32_t gid = bins.slot_gaussian[bins.tile_slots[begin + k]];
      const float* g = proj + (int64_t)kProjStride * gid;
      u[k] = g[kU]; v[k] = g[kV]; A[k] = g[kConicA]; B[k] = g[kConicB]; C[k] = g[kConicC];
      opacity[k] = g[kOpacity]; red[k] = g[kRed]; green[k] = g[kGreen]; blue[k] = g[kBlue];
      depth[k] = g[kDepth]; ex[k] = g[kExtentX]; ey[k] = g[kExtentY];
      exclusive[k] = (excl && excl[gid]) ? 1 : 0;
      pos[k] = k;
    }
    pad();
  }

  // The Gaussians of a tile list whose support box reaches a pixel-centre rectangle (the
  // others have alpha < 1/255 on all of it).
  void select(const TileList& tile, float x_lo, float x_hi, float y_lo, float y_hi) {
    reset(tile.size);
    int32_t n = 0;
    for (int32_t k = 0; k < tile.size; ++k) {
      if (!(tile.u[k] + tile.ex[k] >= x_lo && tile.u[k] - tile.ex[k] <= x_hi &&
            tile.v[k] + tile.ey[k] >= y_lo && tile.v[k] - tile.ey[k] <= y_hi))
        continue;
      u[n] = tile.u[k]; v[n] = tile.v[k]; A[n] = tile.A[k]; B[n] = tile.B[k];
      C[n] = tile.C[k]; opacity[n] = tile.opacity[k]; red[n] = tile.red[k];
      green[n] = tile.green[k]; blue[n] = tile.blue[k]; depth[n] = tile.depth[k];
      ex[n] = tile.ex[k]; ey[n] = tile.ey[k]; exclusive[n] = tile.exclusive[k];
      pos[n] = tile.pos[k];
      ++n;
    }
    size = n;
    pad();
  }

 private:
  void reset(int32_t count) {
    size = count;
    const size_t padded = (size_t)(count + kBatch - 1) / kBatch * kBatch;
    for (auto* vec : {&u, &v, &A, &B, &C, &opacity, &red, &green, &blue, &depth, &ex, &ey})
      if (vec->size() < padded) vec->resize(padded);
    if (exclusive.size() < padded) { exclusive.resize(padded); pos.resize(padded); }
  }
  void pad() {  // transparent entries up to the next multiple of kBatch
    for (int32_t k = size; k % kBatch; ++k) {
      u[k] = v[k] = A[k] = B[k] = C[k] = opacity[k] = 0.f;
      red[k] = green[k] = blue[k] = depth[k] = ex[k] = ey[k] = 0.f;
      exclusive[k] = 0;
      pos[k] = -1;
    }
  }
};

// Calls fn(quarter_list, row, col) for every pixel of a tile, quarter by quarter.
template <typename PixelFn>
inline void for_each_pixel(const TileGeometry& geo, const TileList& tile, TileList& quarter,
                           PixelFn&& fn) {
  for (int qy = 0; qy < geo.height; qy += kQuad)
    for (int qx = 0; qx < geo.width; qx += kQuad) {
      const int rows = std::min(kQuad, geo.height - qy), cols = std::min(kQuad, geo.width - qx);
      quarter.select(tile, (float)(geo.x0 + qx) + 0.5f, (float)(geo.x0 + qx + cols) - 0.5f,
                     (float)(geo.y0 + qy) + 0.5f, (float)(geo.y0 + qy + rows) - 0.5f);
      for (int row = qy; row < qy + rows; ++row)
        for (int col = qx; col < qx + cols; ++col) fn(quarter, row, col);
    }
}

// Alphas (and Gaussian values) of kBatch consecutive list entries at one pixel centre;
// returns how many of them reach 1/255 (0 lets the caller skip the batch without branches
// per entry).
inline int batch_alpha(const TileList& row, int32_t first, float px, float py, float* alpha,
                       float* gauss) {
  const float* u = row.u.data() + first; const float* v = row.v.data() + first;
  const float* A = row.A.data() + first; const float* B = row.B.data() + first;
  const float* C = row.C.data() + first; const float* o = row.opacity.data() + first;
  int reaching = 0;
#pragma omp simd reduction(+ : reaching)
  for (int k = 0; k < kBatch; ++k) {
    float G;
    alpha[k] = splat_alpha(u[k], v[k], A[k], B[k], C[k], o[k], px, py, G);
    gauss[k] = G;
    reaching += alpha[k] >= kAlphaMin ? 1 : 0;
  }
  return reaching;
}

}  // namespace

void render_forward_cpu(const CameraParams& cam, const float* proj, const uint8_t* exclusive,
                        const TileBins& bins, const float* background, float* rgb, float* alpha,
                        float* depth, const PixelState& state) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
#pragma omp parallel if (num_tiles >= kParallelTiles)
  {
    TileList tile_list, quarter;
#pragma omp for schedule(dynamic, 1)
    for (int tile = 0; tile < num_tiles; ++tile) {
      const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
      tile_list.gather(bins, tile, proj, exclusive);
      for_each_pixel(geo, tile_list, quarter, [&](const TileList& list, int row, int col) {
          const float px = (float)(geo.x0 + col) + 0.5f, py = (float)(geo.y0 + row) + 0.5f;
          float T = 1.f, acc_r = 0.f, acc_g = 0.f, acc_b = 0.f, acc_d = 0.f;
          int32_t n_contrib = 0, winner = -1;
          bool taken = false, done = false;
          for (int32_t first = 0; first < list.size && !done; first += kBatch) {
            alignas(32) float a[kBatch], G[kBatch];
            if (batch_alpha(list, first, px, py, a, G) == 0) continue;
            for (int k = 0; k < kBatch; ++k) {
              if (a[k] < kAlphaMin) continue;
              const int32_t e = first + k;
              const bool excl = list.exclusive[e] != 0;
              if (excl && taken) continue;
              const float test_T = T * (1.f - a[k]);
              if (test_T < kTransmittanceMin) { done = true; break; }
              const float w = a[k] * T;
              acc_r += w * list.red[e]; acc_g += w * list.green[e]; acc_b += w * list.blue[e];
              acc_d += w * list.depth[e];
              T = test_T;
              n_contrib = list.pos[e] + 1;
              if (excl) { taken = true; winner = list.pos[e]; }
            }
          }
          const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col;
          rgb[3 * pix] = acc_r + T * background[0];
          rgb[3 * pix + 1] = acc_g + T * background[1];
          rgb[3 * pix + 2] = acc_b + T * background[2];
          alpha[pix] = 1.f - T;
          depth[pix] = acc_d;
          state.final_T[pix] = T;
          state.n_contrib[pix] = n_contrib;
          state.exclusive_winner[pix] = winner;
      });
    }
  }
}

void render_backward_cpu(const CameraParams& cam, const float* proj, const uint8_t* exclusive,
                         const TileBins& bins, const float* background, const PixelState& state,
                         const float* grad_rgb, const float* grad_alpha, const float* grad_depth,
                         float* slot_grads) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
#pragma omp parallel if (num_tiles >= kParallelTiles)
  {
    TileList tile_list, quarter;
    std::vector<float> tile_grads;  // kSlotStride per tile-list entry, summed over pixels
#pragma omp for schedule(dynamic, 1)
    for (int tile = 0; tile < num_tiles; ++tile) {
      const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
      const int32_t begin = bins.tile_start[tile], count = bins.tile_start[tile + 1] - begin;
      tile_grads.assign((size_t)count * kSlotStride, 0.f);
      tile_list.gather(bins, tile, proj, exclusive);
      // Pixels in a fixed order, each walking its list backwards: deterministic sums.
      for_each_pixel(geo, tile_list, quarter, [&](const TileList& list, int row, int col) {
          const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col;
          const float px = (float)(geo.x0 + col) + 0.5f, py = (float)(geo.y0 + row) + 0.5f;
          const float g_r = grad_rgb[3 * pix], g_g = grad_rgb[3 * pix + 1];
          const float g_b = grad_rgb[3 * pix + 2], g_d = grad_depth[pix];
          float T = state.final_T[pix];
          // T_N (bg·dL/dC - dL/dA): how the background and alpha outputs depend on T_N.
          const float tail = T * (background[0] * g_r + background[1] * g_g +
                                  background[2] * g_b - grad_alpha[pix]);
          float later = 0.f;  // sum over later blended entries of w·(c·dL/dC + z·dL/dD)
          const int32_t winner = state.exclusive_winner[pix], n_contrib = state.n_contrib[pix];
          // entries with tile-list position < n_contrib (pos increases along the list)
          const int32_t end = (int32_t)(std::lower_bound(list.pos.begin(), list.pos.begin() + list.size,
                                                         n_contrib) - list.pos.begin());
          for (int32_t batch_end = end; batch_end > 0; batch_end -= kBatch) {
            const int32_t first = batch_end >= kBatch ? batch_end - kBatch : 0;
            alignas(32) float a[kBatch], G[kBatch];
            if (batch_alpha(list, first, px, py, a, G) == 0) continue;
            for (int32_t e = batch_end - 1; e >= first; --e) {
              const int k = e - first;
              if (a[k] < kAlphaMin || (list.exclusive[e] != 0 && winner != list.pos[e])) continue;
              const float one_minus = 1.f - a[k];
              const float T_before = T / one_minus;
              const float w = a[k] * T_before;
              const float shade = list.red[e] * g_r + list.green[e] * g_g + list.blue[e] * g_b +
                                  list.depth[e] * g_d;
              const float g_alpha = T_before * shade - (later + tail) / one_minus;
              float* out = &tile_grads[(size_t)list.pos[e] * kSlotStride];
              splat_alpha_backward(list.u[e], list.v[e], list.A[e], list.B[e], list.C[e],
                                   list.opacity[e], px, py, G[k], g_alpha, out);
              out[kGradRed] += w * g_r; out[kGradGreen] += w * g_g; out[kGradBlue] += w * g_b;
              out[kGradDepth] += w * g_d;
              later += w * shade;
              T = T_before;
            }
          }
      });
      for (int32_t pos = 0; pos < count; ++pos)
        std::memcpy(slot_grads + (int64_t)kSlotStride * bins.tile_slots[begin + pos],
                    &tile_grads[(size_t)pos * kSlotStride], sizeof(float) * kSlotStride);
    }
  }
}

void preprocess_backward_cpu(const CameraParams& cam, const GaussianInputs& in, const float* proj,
                             const int64_t* slot_offset, const float* slot_grads,
                             const GaussianGrads& grads) {
  (void)proj;
#pragma omp parallel for schedule(static) if (in.num >= kParallelGaussians)
  for (int64_t i = 0; i < in.num; ++i) preprocess_backward_one(cam, in, i, slot_offset, slot_grads, grads);
}

}  // namespace raster
}  // namespace fgs
