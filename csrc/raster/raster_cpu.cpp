// CPU (OpenMP) kernels of the Gaussian rasterizer. Per-Gaussian work is a parallel loop over
// Gaussians; binning sorts the visible Gaussians once by (depth, index) and fills the tile
// lists in that order, so every tile list is sorted front to back. Blending runs one tile per
// task (dynamic schedule): the tile's Gaussians are gathered into a structure-of-arrays list,
// each 8x8 quarter of the tile keeps the entries whose support box reaches it, and each row of
// 8 pixels of a quarter walks that list front to back with one SIMD lane per pixel (GCC vector
// extensions); a lane stops when its pixel saturates (like one CUDA thread), the row when all
// lanes have. The backward walks each row's list in reverse, one lane per pixel, and sums the
// gradients of each list entry per lane in a tile-local buffer, then over the lanes, into that
// entry's (Gaussian, tile) slot: no atomics, and the same bits for any thread count.

// GCC only vectorises selects (min, comparisons) of auto-vectorised loops when it may assume
// FP operations do not trap (the blending loops themselves use explicit vector types). No code
// here relies on floating-point exception flags.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("no-trapping-math")
#endif
#include <algorithm>
#include <cmath>
#include <cstring>
#include <new>
#if defined(__AVX__)
#include <immintrin.h>
#endif
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
  // By depth, ties by index (keys are unique: the same order for any thread count). Large
  // lists are sorted as two halves in parallel, then merged.
  const size_t half = order.size() / 2;
  if (half >= (size_t)kParallelGaussians) {
#pragma omp parallel sections
    {
#pragma omp section
      std::sort(order.begin(), order.begin() + half);
#pragma omp section
      std::sort(order.begin() + half, order.end());
    }
    std::inplace_merge(order.begin(), order.begin() + half, order.end());
  } else {
    std::sort(order.begin(), order.end());
  }
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

constexpr int kBatch = 8;  // lists are padded to a multiple of this many entries

constexpr int kQuad = kTileSize / 2;  // pixels are processed in 8x8 quarters of a tile

// Gaussians in list order as structure-of-arrays, padded to a multiple of kBatch with fully
// transparent entries; pos is the position in the tile's list.
struct TileList {
  std::vector<float> u, v, A, B, C, opacity, red, green, blue, depth, ex, ey;
  std::vector<int32_t> exclusive, pos, gid;  // exclusive: 1 for a flagged / grouped Gaussian
  int32_t size = 0;

  // All Gaussians of a tile.
  void gather(const TileBins& bins, int tile, const float* proj, const ExclusiveRule& excl) {
    const int32_t begin = bins.tile_start[tile];
    reset(bins.tile_start[tile + 1] - begin);
    constexpr int32_t kAhead = 8;  // two-stage software prefetch of the random-order reads
    for (int32_t k = 0; k < size; ++k) {
      if (k + 2 * kAhead < size) __builtin_prefetch(bins.slot_gaussian + bins.tile_slots[begin + k + 2 * kAhead]);
      if (k + kAhead < size)
        __builtin_prefetch(proj + (int64_t)kProjStride * bins.slot_gaussian[bins.tile_slots[begin + k + kAhead]]);
      const int32_t id = bins.slot_gaussian[bins.tile_slots[begin + k]];
      const float* g = proj + (int64_t)kProjStride * id;
      u[k] = g[kU]; v[k] = g[kV]; A[k] = g[kConicA]; B[k] = g[kConicB]; C[k] = g[kConicC];
      opacity[k] = g[kOpacity]; red[k] = g[kRed]; green[k] = g[kGreen]; blue[k] = g[kBlue];
      depth[k] = g[kDepth]; ex[k] = g[kExtentX]; ey[k] = g[kExtentY];
      exclusive[k] = excl.flags ? (excl.flags[id] ? 1 : 0) : (excl.next && excl.next[id] >= 0 ? 1 : 0);
      pos[k] = k;
      gid[k] = id;
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
      pos[n] = tile.pos[k]; gid[n] = tile.gid[k];
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
    if (exclusive.size() < padded) { exclusive.resize(padded); pos.resize(padded); gid.resize(padded); }
  }
  void pad() {  // transparent entries up to the next multiple of kBatch
    for (int32_t k = size; k % kBatch; ++k) {
      u[k] = v[k] = A[k] = B[k] = C[k] = opacity[k] = 0.f;
      red[k] = green[k] = blue[k] = depth[k] = ex[k] = ey[k] = 0.f;
      exclusive[k] = 0;
      pos[k] = -1;
      gid[k] = -1;
    }
  }
};

// Calls fn(quarter_list, row, col0, cols) for every row of every 8x8 quarter of a tile: the
// pixels (row, col0 .. col0 + cols - 1) are processed together, one SIMD lane each.
template <typename RowFn>
inline void for_each_row(const TileGeometry& geo, const TileList& tile, TileList& quarter,
                         RowFn&& fn) {
  for (int qy = 0; qy < geo.height; qy += kQuad)
    for (int qx = 0; qx < geo.width; qx += kQuad) {
      const int rows = std::min(kQuad, geo.height - qy), cols = std::min(kQuad, geo.width - qx);
      quarter.select(tile, (float)(geo.x0 + qx) + 0.5f, (float)(geo.x0 + qx + cols) - 0.5f,
                     (float)(geo.y0 + qy) + 0.5f, (float)(geo.y0 + qy + rows) - 0.5f);
      for (int row = qy; row < qy + rows; ++row) fn(quarter, row, qx, cols);
    }
}

constexpr int kLanes = kQuad;

// 32-byte aligned storage for per-lane accumulators.
template <typename T>
struct AlignedAllocator {
  using value_type = T;
  AlignedAllocator() = default;
  template <typename U> AlignedAllocator(const AlignedAllocator<U>&) {}
  T* allocate(size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), std::align_val_t(32))); }
  void deallocate(T* p, size_t) { ::operator delete(p, std::align_val_t(32)); }
  bool operator==(const AlignedAllocator&) const { return true; }
};  // pixels of a quarter row, blended together (one per lane)

// True when entry e's support box misses the pixel-centre row y = py.
inline bool misses_row(const TileList& list, int32_t e, float py) {
  return !(list.v[e] + list.ey[e] >= py && list.v[e] - list.ey[e] <= py);
}

// One float / int32 per lane (GCC vector extensions: AVX with -march=native, otherwise split
// by the compiler into narrower vectors).
typedef float LaneF __attribute__((vector_size(4 * kLanes)));
typedef int32_t LaneI __attribute__((vector_size(4 * kLanes)));

inline LaneF lanes_of(float value) { return LaneF{} + value; }

// Whether any lane of a mask (0 / -1 per lane) is set.
inline bool any_lane(LaneI mask) {
#if defined(__AVX__)
  static_assert(sizeof(LaneI) == sizeof(__m256i));
  const __m256i bits = (__m256i)mask;
  return !_mm256_testz_si256(bits, bits);
#else
  int32_t any = 0;
  for (int l = 0; l < kLanes; ++l) any |= mask[l];
  return any != 0;
#endif
}

// exp_nonpositive (common/blend.h) on every lane: the same steps, floor through integer
// truncation (exact here: |x·log2 e| < 2^31).
inline LaneF exp_nonpositive_lanes(LaneF x) {
  x = x > -80.f ? x : lanes_of(-80.f);
  const LaneF t = x * 1.4426950408889634f + 0.5f;
  const LaneI truncated = __builtin_convertvector(t, LaneI);
  const LaneF truncated_f = __builtin_convertvector(truncated, LaneF);
  const LaneI above = truncated_f > t;  // -1 where truncation rounded up (negative t)
  const LaneF n = truncated_f + __builtin_convertvector(above, LaneF);
  const LaneF r = (x - n * 0.693145751953125f) - n * 1.428606765330187e-06f;
  return exp_reduced_taylor(r) * (LaneF)((truncated + above + 127) << 23);
}

// splat_alpha (common/blend.h) of one Gaussian at the pixel centres (px[lane], py).
inline LaneF splat_alpha_lanes(float u, float v, float A, float B, float C, float opacity,
                               LaneF px, float py, LaneF& G) {
  const LaneF dx = u - px;
  const float dy = v - py;
  const LaneF power = -0.5f * (A * dx * dx + C * dy * dy) - B * dx * dy;
  G = power <= 0.f ? exp_nonpositive_lanes(power) : LaneF{};
  const LaneF a = opacity * G;
  return a < kAlphaMax ? a : lanes_of(kAlphaMax);
}

// The group rule (ExclusiveRule) of a tile's list: for every grouped entry with exactly one
// earlier member in its group (FPGO's pairs of lenses), that member's position in the tile's
// list (forward, which has just evaluated that member's alpha on the same row: see usable) or
// its projected parameters (backward, which walks the list in reverse); entries with several
// earlier members walk the ring per row.
struct EarlierMembers {
  std::vector<float> u, v, A, B, C, opacity;
  std::vector<int32_t> one;      // earlier_group_member of the entry's Gaussian (or kNoEarlierMember)
  std::vector<int32_t> partner;  // forward, one >= 0: tile-list position of that member, -1: absent
  // Forward: per tile-list position of a grouped entry, its alpha >= 1/255 lanes on the row with
  // serial number usable_row (a member absent from a row has alpha < 1/255 on all of it).
  std::vector<LaneI, AlignedAllocator<LaneI>> usable;
  std::vector<int64_t> usable_row;

  void fill(const TileList& tile, const float* proj, const ExclusiveRule& rule, bool forward) {
    const size_t n = (size_t)tile.size;
    for (auto* vec : {&u, &v, &A, &B, &C, &opacity})
      if (vec->size() < n) vec->resize(n);
    if (one.size() < n) { one.resize(n); partner.resize(n); usable.resize(n); }
    usable_row.assign(n, -1);
    for (int32_t k = 0; k < tile.size; ++k) {
      one[k] = tile.exclusive[k] ? rule.earlier[tile.gid[k]] : kNoEarlierMember;
      if (one[k] < 0) continue;
      const float* g = proj + (int64_t)kProjStride * one[k];
      if (forward) {
        partner[k] = position_in(tile, g[kDepth], one[k]);
      } else {
        u[k] = g[kU]; v[k] = g[kV]; A[k] = g[kConicA]; B[k] = g[kConicB]; C[k] = g[kConicC];
        opacity[k] = g[kOpacity];
      }
    }
  }

  // Position of Gaussian p (camera depth `depth`) in the tile's list, sorted by (depth, index);
  // -1 when it is not there.
  static int32_t position_in(const TileList& tile, float depth, int32_t p) {
    int32_t lo = 0, hi = tile.size;
    while (lo < hi) {
      const int32_t mid = (lo + hi) / 2;
      if (blends_before(tile.depth[mid], tile.gid[mid], depth, p)) lo = mid + 1; else hi = mid;
    }
    return lo < tile.size && tile.gid[lo] == p ? lo : -1;
  }

  // earlier_group_member_blends (common/blend.h) on every lane for the entry at tile-list
  // position k (Gaussian m): -1 where an earlier member has alpha >= 1/255 at the lane's pixel.
  // A single earlier member's parameters are there after fill(..., forward = false) only.
  LaneI blocked(int32_t k, const ExclusiveRule& rule, const float* proj, int32_t m, LaneF px,
                float py) const {
    LaneF G;
    if (one[k] >= 0)
      return splat_alpha_lanes(u[k], v[k], A[k], B[k], C[k], opacity[k], px, py, G) >= kAlphaMin;
    LaneI out{};
    if (one[k] == kSeveralEarlierMembers) {
      const float depth_m = proj[(int64_t)kProjStride * m + kDepth];
      for (int32_t p = rule.next[m]; p != m && p >= 0; p = rule.next[p]) {
        const float* g = proj + (int64_t)kProjStride * p;
        if (!blends_before(g[kDepth], p, depth_m, m)) continue;
        out |= splat_alpha_lanes(g[kU], g[kV], g[kConicA], g[kConicB], g[kConicC], g[kOpacity],
                                 px, py, G) >= kAlphaMin;
      }
    }
    return out;
  }

  // Forward: records the alpha >= 1/255 lanes of the grouped entry at tile-list position k on
  // row `row` and returns blocked(...) for it (when `wanted`), reading a single earlier member's
  // lanes from what was recorded on this row.
  LaneI record_and_block(int32_t k, int64_t row, LaneI usable_lanes, bool wanted,
                         const ExclusiveRule& rule, const float* proj, int32_t m, LaneF px,
                         float py) {
    usable[k] = usable_lanes;
    usable_row[k] = row;
    if (!wanted || one[k] == kNoEarlierMember) return LaneI{};
    if (one[k] >= 0) {
      const int32_t q = partner[k];
      return q >= 0 && usable_row[q] == row ? usable[q] : LaneI{};
    }
    return blocked(k, rule, proj, m, px, py);
  }
};

}  // namespace

void group_earlier_cpu(int64_t num, const float* proj, const int32_t* next, int32_t* earlier) {
#pragma omp parallel for schedule(static) if (num >= kParallelGaussians)
  for (int64_t i = 0; i < num; ++i)
    earlier[i] = next[i] >= 0 ? earlier_group_member(proj, next, (int32_t)i) : kNoEarlierMember;
}

// Each quarter row of 8 pixels walks its quarter's list front to back with one SIMD lane per
// pixel; a lane stops (like one CUDA thread) once its transmittance would fall below the
// threshold, and the row stops once all its lanes have. Per pixel, the operations and their
// order are exactly those of the one-pixel-at-a-time loop (inactive lanes add zeros).
void render_forward_cpu(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                        const TileBins& bins, const float* background, float* rgb, float* alpha,
                        float* depth, const PixelState& state) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
  const bool group_rule = exclusive.next != nullptr;
#pragma omp parallel if (num_tiles >= kParallelTiles)
  {
    TileList tile_list, quarter;
    EarlierMembers earlier;
    int64_t row_serial = 0;  // numbers every quarter row this thread processes
#pragma omp for schedule(dynamic, 1)
    for (int tile = 0; tile < num_tiles; ++tile) {
      const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
      tile_list.gather(bins, tile, proj, exclusive);
      if (group_rule) earlier.fill(tile_list, proj, exclusive, /*forward=*/true);
      for_each_row(geo, tile_list, quarter, [&](const TileList& list, int row, int col0, int cols) {
          const float py = (float)(geo.y0 + row) + 0.5f;
          ++row_serial;
          LaneF px, T = lanes_of(1.f), acc_r{}, acc_g{}, acc_b{}, acc_d{};
          LaneI n_contrib{}, winner = LaneI{} - 1, taken{}, done{};  // masks are 0 / -1
          for (int l = 0; l < kLanes; ++l) {
            px[l] = (float)(geo.x0 + col0 + l) + 0.5f;
            done[l] = l < cols ? 0 : -1;  // lanes past the image edge never blend
          }
          for (int32_t e = 0; e < list.size; ++e) {
            // every few entries: stop once every lane has saturated
            if ((e & 3) == 0 && !any_lane(~done)) break;
            if (misses_row(list, e, py)) continue;
            const bool global_excl = list.exclusive[e] && !group_rule;
            const LaneI excl = LaneI{} - (global_excl ? 1 : 0);
            // a global-rule exclusive entry cannot blend where every open lane has taken one
            if (global_excl && !any_lane(~done & ~taken)) continue;
            LaneF G;
            const LaneF a = splat_alpha_lanes(list.u[e], list.v[e], list.A[e], list.B[e], list.C[e],
                                              list.opacity[e], px, py, G);
            const LaneF test_T = T * (1.f - a);
            LaneI candidate = ~done & (a >= kAlphaMin) & ~(excl & taken);
            if (group_rule && list.exclusive[e])
              candidate &= ~earlier.record_and_block(list.pos[e], row_serial, a >= kAlphaMin,
                                                     any_lane(candidate), exclusive, proj,
                                                     list.gid[e], px, py);
            const LaneI stop = candidate & (test_T < kTransmittanceMin);
            if (!any_lane(candidate)) continue;
            const LaneI blend = candidate & ~stop;
            done |= stop;
            const LaneF w = blend ? a * T : LaneF{};
            acc_r += w * list.red[e]; acc_g += w * list.green[e]; acc_b += w * list.blue[e];
            acc_d += w * list.depth[e];
            T = blend ? test_T : T;
            n_contrib = blend ? LaneI{} + (list.pos[e] + 1) : n_contrib;
            winner = (blend & excl) ? LaneI{} + list.pos[e] : winner;
            taken |= blend & excl;
          }
          for (int l = 0; l < cols; ++l) {
            const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col0 + l;
            rgb[3 * pix] = acc_r[l] + T[l] * background[0];
            rgb[3 * pix + 1] = acc_g[l] + T[l] * background[1];
            rgb[3 * pix + 2] = acc_b[l] + T[l] * background[2];
            alpha[pix] = 1.f - T[l];
            depth[pix] = acc_d[l];
            state.final_T[pix] = T[l];
            state.n_contrib[pix] = n_contrib[l];
            state.exclusive_winner[pix] = winner[l];
          }
      });
    }
  }
}

// The backward walks each quarter row's list in reverse, one lane per pixel, from the last
// entry any lane blended; a lane only takes the entries its pixel blended (position below its
// n_contrib, alpha >= 1/255, the winning exclusive one). Each entry's gradients are summed per
// lane over the tile's pixels in a fixed order, then over the lanes, and written to the entry's
// (Gaussian, tile) slot: no atomics, the same bits for any thread count.
void render_backward_cpu(const CameraParams& cam, const float* proj, const ExclusiveRule& exclusive,
                         const TileBins& bins, const float* background, const PixelState& state,
                         const float* grad_rgb, const float* grad_alpha, const float* grad_depth,
                         float* slot_grads) {
  const int num_tiles = bins.tiles_x * bins.tiles_y;
  const bool group_rule = exclusive.next != nullptr;
#pragma omp parallel if (num_tiles >= kParallelTiles)
  {
    TileList tile_list, quarter;
    EarlierMembers earlier;
    // per tile-list entry: kSlotStride fields x kLanes lanes, summed over the tile's rows
    std::vector<float, AlignedAllocator<float>> lane_grads;
#pragma omp for schedule(dynamic, 1)
    for (int tile = 0; tile < num_tiles; ++tile) {
      const TileGeometry geo = tile_geometry(cam, bins.tiles_x, tile);
      const int32_t begin = bins.tile_start[tile], count = bins.tile_start[tile + 1] - begin;
      lane_grads.assign((size_t)count * kSlotStride * kLanes, 0.f);
      tile_list.gather(bins, tile, proj, exclusive);
      if (group_rule) earlier.fill(tile_list, proj, exclusive, /*forward=*/false);
      for_each_row(geo, tile_list, quarter, [&](const TileList& list, int row, int col0, int cols) {
          const float py = (float)(geo.y0 + row) + 0.5f;
          LaneF px, T = lanes_of(1.f), tail{}, g_r{}, g_g{}, g_b{}, g_d{};
          LaneF later{};  // sum over later blended entries of w·(c·dL/dC + z·dL/dD)
          LaneI winner = LaneI{} - 1, n_contrib{};  // lanes past the image edge take nothing
          int32_t max_contrib = 0;
          for (int l = 0; l < kLanes; ++l) {
            px[l] = (float)(geo.x0 + col0 + l) + 0.5f;
            if (l >= cols) continue;
            const int64_t pix = (int64_t)(geo.y0 + row) * cam.width + geo.x0 + col0 + l;
            g_r[l] = grad_rgb[3 * pix]; g_g[l] = grad_rgb[3 * pix + 1];
            g_b[l] = grad_rgb[3 * pix + 2]; g_d[l] = grad_depth[pix];
            T[l] = state.final_T[pix];
            // T_N (bg·dL/dC - dL/dA): how the background and alpha outputs depend on T_N.
            tail[l] = T[l] * (background[0] * g_r[l] + background[1] * g_g[l] +
                              background[2] * g_b[l] - grad_alpha[pix]);
            winner[l] = state.exclusive_winner[pix];
            n_contrib[l] = state.n_contrib[pix];
            max_contrib = std::max(max_contrib, n_contrib[l]);
          }
          // entries with tile-list position < max n_contrib (pos increases along the list)
          const int32_t end = (int32_t)(std::lower_bound(list.pos.begin(), list.pos.begin() + list.size,
                                                         max_contrib) - list.pos.begin());
          for (int32_t e = end - 1; e >= 0; --e) {
            if (misses_row(list, e, py)) continue;
            const float u = list.u[e], v = list.v[e], A = list.A[e], B = list.B[e], C = list.C[e];
            const float o = list.opacity[e];
            const int32_t pos = list.pos[e];
            LaneF G;
            const LaneF a = splat_alpha_lanes(u, v, A, B, C, o, px, py, G);
            LaneI taken = (pos < n_contrib) & (a >= kAlphaMin);
            if (list.exclusive[e]) {
              if (!group_rule)
                taken &= winner == pos;
              else if (any_lane(taken))
                taken &= ~earlier.blocked(list.pos[e], exclusive, proj, list.gid[e], px, py);
            }
            if (!any_lane(taken)) continue;  // e.g. outside the ellipse on this whole row
            const LaneF inv_one_minus = 1.f / (1.f - a);
            const LaneF T_before = T * inv_one_minus;
            const LaneF w = taken ? a * T_before : LaneF{};
            const LaneF shade = list.red[e] * g_r + list.green[e] * g_g + list.blue[e] * g_b +
                                list.depth[e] * g_d;
            const LaneF g_alpha = taken ? T_before * shade - (later + tail) * inv_one_minus : LaneF{};
            // splat_alpha_backward (common/blend.h) on every lane
            const LaneF dx = u - px;
            const float dy = v - py;
            const LaneI unclamped = o * G <= kAlphaMax;
            const LaneF g_opacity = unclamped ? G * g_alpha : LaneF{};
            const LaneF g_power = unclamped ? G * o * g_alpha : LaneF{};
            LaneF* out = reinterpret_cast<LaneF*>(&lane_grads[(size_t)pos * kSlotStride * kLanes]);
            out[kGradU] += g_power * (-A * dx - B * dy);
            out[kGradV] += g_power * (-C * dy - B * dx);
            out[kGradConicA] += -0.5f * dx * dx * g_power;
            out[kGradConicB] += -dx * dy * g_power;
            out[kGradConicC] += -0.5f * dy * dy * g_power;
            out[kGradOpacity] += g_opacity;
            out[kGradRed] += w * g_r;
            out[kGradGreen] += w * g_g;
            out[kGradBlue] += w * g_b;
            out[kGradDepth] += w * g_d;
            later += w * shade;
            T = taken ? T_before : T;
          }
      });
      for (int32_t pos = 0; pos < count; ++pos) {
        float* slot = slot_grads + (int64_t)kSlotStride * bins.tile_slots[begin + pos];
        const float* lanes = &lane_grads[(size_t)pos * kSlotStride * kLanes];
        for (int f = 0; f < kSlotStride; ++f) {
          float sum = 0.f;
          for (int l = 0; l < kLanes; ++l) sum += lanes[f * kLanes + l];
          slot[f] = sum;
        }
      }
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
