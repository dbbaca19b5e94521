// CPU (OpenMP) kernels of the Gaussian rasterizer. Per-Gaussian work is a parallel loop over
// Gaussians; binning sorts the visible Gaussians once by (depth, index) and fills the tile
// lists in that order, so every tile list is sorted front to back; blending runs one tile
// per task (dynamic schedule) with Gaussian-major loops over the tile's pixels, which
// vectorise, and stops a tile once all its pixels are saturated. The backward walks each
// tile's list in reverse and writes one gradient slot per (Gaussian, tile): no atomics,
// deterministic for any thread count.
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

constexpr int kTilePixels = kTileSize * kTileSize;

// Order-preserving map of a float to an unsigned integer (for sort keys).
inline uint32_t orderable_bits(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
}

// Pixel columns/rows of a tile that a Gaussian's support box can reach (inclusive range,
// relative to the tile origin); false if none. Conservative: floor of the box ends.
inline bool tile_pixel_range(float centre, float extent, int origin, int size, int& lo, int& hi) {
  const float a = std::floor(centre - extent) - (float)origin;
  const float b = std::floor(centre + extent) - (float)origin;
  lo = a > 0.f ? (int)a : 0;
  hi = b < (float)(size - 1) ? (int)b : size - 1;
  return lo <= hi;
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
#pragma omp parallel for schedule(static)
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

void render_forward_cpu(const CameraParams& cam, const float* proj, const uint8_t* exclusive,
                        const TileBins& bins, const float* background, float* rgb, float* alpha,
                        float* depth, const PixelState& state) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
#pragma omp parallel for schedule(dynamic, 1)
  for (int tile = 0; tile < num_tiles; ++tile) {
    const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
    alignas(64) float T[kTilePixels], acc_r[kTilePixels], acc_g[kTilePixels], acc_b[kTilePixels],
        acc_d[kTilePixels];
    alignas(64) int32_t n_contrib[kTilePixels], winner[kTilePixels], done[kTilePixels],
        taken[kTilePixels];
    for (int p = 0; p < kTilePixels; ++p) {
      T[p] = 1.f; acc_r[p] = acc_g[p] = acc_b[p] = acc_d[p] = 0.f;
      n_contrib[p] = 0; winner[p] = -1; taken[p] = 0;
      done[p] = ((p % kTileSize) < geo.width && (p / kTileSize) < geo.height) ? 0 : 1;
    }
    int num_done = kTilePixels - geo.width * geo.height;
    const int32_t begin = bins.tile_start[tile], end = bins.tile_start[tile + 1];
    for (int32_t pos = 0; pos < end - begin && num_done < kTilePixels; ++pos) {
      const int32_t gid = bins.slot_gaussian[bins.tile_slots[begin + pos]];
      const float* g = proj + kProjStride * (int64_t)gid;
      int c0, c1, r0, r1;
      if (!tile_pixel_range(g[kU], g[kExtentX], geo.x0, geo.width, c0, c1) ||
          !tile_pixel_range(g[kV], g[kExtentY], geo.y0, geo.height, r0, r1))
        continue;
      const float u = g[kU], v = g[kV], A = g[kConicA], B = g[kConicB], C = g[kConicC];
      const float opacity = g[kOpacity], red = g[kRed], green = g[kGreen], blue = g[kBlue];
      const float z = g[kDepth];
      const int32_t excl = (exclusive && exclusive[gid]) ? 1 : 0;
      int newly_done = 0;
      for (int row = r0; row <= r1; ++row) {
        const float py = (float)(geo.y0 + row) + 0.5f;
#pragma omp simd reduction(+ : newly_done)
        for (int col = c0; col <= c1; ++col) {
          const int p = row * kTileSize + col;
          float G;
          const float a = splat_alpha(u, v, A, B, C, opacity, (float)(geo.x0 + col) + 0.5f, py, G);
          const int32_t valid = (a >= kAlphaMin) & (done[p] == 0) & ((excl & taken[p]) == 0);
          const float test_T = T[p] * (1.f - a);
          const int32_t stop = valid & (test_T < kTransmittanceMin);
          const int32_t blend = valid & (stop == 0);
          const float w = blend ? a * T[p] : 0.f;
          acc_r[p] += w * red; acc_g[p] += w * green; acc_b[p] += w * blue; acc_d[p] += w * z;
          T[p] = blend ? test_T : T[p];
          done[p] |= stop;
          newly_done += stop;
          n_contrib[p] = blend ? pos + 1 : n_contrib[p];
          const int32_t won = blend & excl;
          taken[p] |= won;
          winner[p] = won ? pos : winner[p];
        }
      }
      num_done += newly_done;
    }
    for (int row = 0; row < geo.height; ++row)
      for (int col = 0; col < geo.width; ++col) {
        const int p = row * kTileSize + col;
        const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col;
        rgb[3 * pix] = acc_r[p] + T[p] * background[0];
        rgb[3 * pix + 1] = acc_g[p] + T[p] * background[1];
        rgb[3 * pix + 2] = acc_b[p] + T[p] * background[2];
        alpha[pix] = 1.f - T[p];
        depth[pix] = acc_d[p];
        state.final_T[pix] = T[p];
        state.n_contrib[pix] = n_contrib[p];
        state.exclusive_winner[pix] = winner[p];
      }
  }
}

void render_backward_cpu(const CameraParams& cam, const float* proj, const uint8_t* exclusive,
                         const TileBins& bins, const float* background, const PixelState& state,
                         const float* grad_rgb, const float* grad_alpha, const float* grad_depth,
                         float* slot_grads) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
#pragma omp parallel for schedule(dynamic, 1)
  for (int tile = 0; tile < num_tiles; ++tile) {
    const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
    // Per pixel: transmittance before the current entry, sum over later entries of
    // w·(c·dL/dC + z·dL/dD), the background/alpha term T_N (bg·dL/dC - dL/dA).
    alignas(64) float T[kTilePixels], later[kTilePixels], tail[kTilePixels], g_r[kTilePixels],
        g_g[kTilePixels], g_b[kTilePixels], g_d[kTilePixels];
    alignas(64) int32_t n_contrib[kTilePixels], winner[kTilePixels];
    int32_t max_contrib = 0;
    for (int p = 0; p < kTilePixels; ++p) {
      const int row = p / kTileSize, col = p % kTileSize;
      T[p] = 1.f; later[p] = tail[p] = g_r[p] = g_g[p] = g_b[p] = g_d[p] = 0.f;
      n_contrib[p] = 0; winner[p] = -1;
      if (row < geo.height && col < geo.width) {
        const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col;
        T[p] = state.final_T[pix];
        g_r[p] = grad_rgb[3 * pix]; g_g[p] = grad_rgb[3 * pix + 1]; g_b[p] = grad_rgb[3 * pix + 2];
        g_d[p] = grad_depth[pix];
        tail[p] = T[p] * (background[0] * g_r[p] + background[1] * g_g[p] +
                          background[2] * g_b[p] - grad_alpha[pix]);
        n_contrib[p] = state.n_contrib[pix];
        winner[p] = state.exclusive_winner[pix];
        max_contrib = std::max(max_contrib, n_contrib[p]);
      }
    }
    const int32_t begin = bins.tile_start[tile];
    for (int32_t pos = max_contrib - 1; pos >= 0; --pos) {
      const int32_t slot = bins.tile_slots[begin + pos];
      const int32_t gid = bins.slot_gaussian[slot];
      const float* g = proj + kProjStride * (int64_t)gid;
      int c0, c1, r0, r1;
      if (!tile_pixel_range(g[kU], g[kExtentX], geo.x0, geo.width, c0, c1) ||
          !tile_pixel_range(g[kV], g[kExtentY], geo.y0, geo.height, r0, r1))
        continue;
      const float u = g[kU], v = g[kV], A = g[kConicA], B = g[kConicB], C = g[kConicC];
      const float opacity = g[kOpacity], red = g[kRed], green = g[kGreen], blue = g[kBlue];
      const float z = g[kDepth];
      const int32_t excl = (exclusive && exclusive[gid]) ? 1 : 0;
      float du = 0.f, dv = 0.f, dA = 0.f, dB = 0.f, dC = 0.f, dop = 0.f;
      float dr = 0.f, dg = 0.f, db = 0.f, dz = 0.f;
      for (int row = r0; row <= r1; ++row) {
        const float py = (float)(geo.y0 + row) + 0.5f;
#pragma omp simd reduction(+ : du, dv, dA, dB, dC, dop, dr, dg, db, dz)
        for (int col = c0; col <= c1; ++col) {
          const int p = row * kTileSize + col;
          const float px = (float)(geo.x0 + col) + 0.5f;
          float G;
          const float a = splat_alpha(u, v, A, B, C, opacity, px, py, G);
          const int32_t active = (pos < n_contrib[p]) & (a >= kAlphaMin) &
                                 ((excl == 0) | (winner[p] == pos));
          const float one_minus = 1.f - a;
          const float T_before = T[p] / one_minus;
          const float w = active ? a * T_before : 0.f;
          const float shade = red * g_r[p] + green * g_g[p] + blue * g_b[p] + z * g_d[p];
          const float g_alpha = active ? T_before * shade - (later[p] + tail[p]) / one_minus : 0.f;
          float d[6] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
          splat_alpha_backward(u, v, A, B, C, opacity, px, py, G, g_alpha, d);
          du += d[0]; dv += d[1]; dA += d[2]; dB += d[3]; dC += d[4]; dop += d[5];
          dr += w * g_r[p]; dg += w * g_g[p]; db += w * g_b[p]; dz += w * g_d[p];
          later[p] += w * shade;
          T[p] = active ? T_before : T[p];
        }
      }
      float* out = slot_grads + (int64_t)kSlotStride * slot;
      out[kGradU] = du; out[kGradV] = dv;
      out[kGradConicA] = dA; out[kGradConicB] = dB; out[kGradConicC] = dC;
      out[kGradOpacity] = dop;
      out[kGradRed] = dr; out[kGradGreen] = dg; out[kGradBlue] = db; out[kGradDepth] = dz;
    }
  }
}

void preprocess_backward_cpu(const CameraParams& cam, const GaussianInputs& in, const float* proj,
                             const int64_t* slot_offset, const float* slot_grads,
                             const GaussianGrads& grads) {
  (void)proj;
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < in.num; ++i) preprocess_backward_one(cam, in, i, slot_offset, slot_grads, grads);
}

}  // namespace raster
}  // namespace fgs
