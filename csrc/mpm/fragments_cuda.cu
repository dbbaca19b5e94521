// CUDA kernels of the damage-gradient partitioning (csrc/common/mpm_fragments.h); the math is the
// CPU kernels' (csrc/mpm/fragments_cpu.cpp). Deterministic: the reference key is a 64-bit integer
// maximum (order-free), and field B is summed per node, one thread per tile node walking its
// cell's particles in their sorted order, colour by colour (as P2G).
#include <cuda_runtime.h>

#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

constexpr int kThreads = 256;
constexpr int kTile = kBlock + 2;  // nodes per tile edge a cell's stencils cover
constexpr int kTileNodes = kTile * kTile * kTile;

inline cudaStream_t as_stream(void* stream) { return static_cast<cudaStream_t>(stream); }
inline unsigned blocks_for(long long n, int threads) { return (unsigned)((n + threads - 1) / threads); }

// Thread t of a launch over the nodes of the (grid, block) keys: its node's index in the grid
// arrays, or -1 for a key outside the grids (skipped).
__device__ inline long long key_node(const int32_t* keys, long long t, const MPMGeometry& geo) {
  const int n_blocks = geo.shape.blocks();
  const int key = keys[t / kBlockNodes];
  if (key < 0 || key >= geo.n_grids * n_blocks) return -1;
  return (long long)(key / n_blocks) * geo.shape.nodes() + (long long)(key % n_blocks) * kBlockNodes + t % kBlockNodes;
}

// True if the stencil of a particle at x lies inside the grid (its nodes base .. base + 2).
__device__ inline bool stencil_in_grid(const float* x, const MPMGeometry& geo) {
  int base[3];
  stencil_base(x, geo, base);
  const int nodes_per_axis[3] = {geo.shape.bx * kBlock, geo.shape.by * kBlock, geo.shape.bz * kBlock};
  for (int d = 0; d < 3; ++d)
    if (!(base[d] >= 0 && base[d] + 2 < nodes_per_axis[d])) return false;
  return true;
}

__global__ void reference_kernel(long long n, const float* x, const int32_t* grid_id, MPMGeometry geo, float mass_eps,
                                 uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                                 DirectionView directions, float* damage_gradient,
                                 int64_t* reference, long long* bounds) {
  const long long q = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (q >= n) return;
  const int g = grid_id[q];
  float* gq = damage_gradient + 3 * q;
  if (g < 0 || g >= geo.n_grids || !stencil_in_grid(x + 3 * q, geo)) {  // its nodes are not in the grids
    gq[0] = gq[1] = gq[2] = 0.f;
    atomicMin(bounds, q);
    return;
  }
  particle_damage_gradient(x + 3 * q, g, geo, grid_mass, grid_damage, mass_eps, gq);
  apply_split_direction(directions, q, gq);
  const int64_t key = damage_key(gq, q);
  if (!key_is_split(key, split_bits)) return;  // a key below the threshold splits no node
  AxisWeights aw[3];
  stencil_weights(x + 3 * q, geo, aw);
  unsigned long long* keys = reinterpret_cast<unsigned long long*>(reference + (long long)g * geo.shape.nodes());
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b)
      for (int c = 0; c < 3; ++c)
        atomicMax(keys + node_index(aw[0].base + a, aw[1].base + b, aw[2].base + c, geo.shape),
                  (unsigned long long)key);
}

// Field A of a node with side-B mass becomes P2G's sum minus side B (split_node_fields).
__global__ void merge_kernel(const int32_t* keys, int n_keys, MPMGeometry geo, GridArrays grid) {
  const long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_keys * kBlockNodes) return;
  const long long idx = key_node(keys, t, geo);
  if (idx < 0) return;
  const long long idx_b = idx + (long long)geo.n_grids * geo.shape.nodes();
  if (grid.mass[idx_b] != 0.f)
    split_node_fields(idx, idx_b, grid.mass, grid.momentum, grid.mass_gradient, grid.position_moment);
}

// One thread block per cell of the colour, one thread per node of the cell's 6x6x6 tile: a split
// node sums the cell's particles on side B into field B (field A keeps P2G's sum of all).
__global__ void partition_color_kernel(BinsView bins, int color_begin, ParticleArrays p, MPMGeometry geo, float dt,
                                       FragmentView frag, GridArrays grid, uint8_t* split_particle,
                                       int32_t* side_mask, uint8_t* side_b_block, long long* bounds) {
  const GridShape s = geo.shape;
  const long long nodes = s.nodes();
  const int n_blocks = s.blocks();
  const int cell = bins.color_cells[color_begin + blockIdx.x];
  const int t = threadIdx.x;
  if (cell < 0 || cell >= bins.n_cells || bins.cell_key[cell] < 0 || bins.cell_key[cell] >= geo.n_grids * n_blocks ||
      bins.cell_start[cell] < 0 || bins.cell_start[cell + 1] > bins.n_particles) {
    if (t == 0) atomicMin(bounds + 1, (long long)(color_begin + blockIdx.x));
    return;
  }
  const int g = bins.cell_key[cell] / n_blocks, block = bins.cell_key[cell] % n_blocks;
  if (t >= kTileNodes) return;
  int b[3];
  block_coords(block, s, b);
  const int node_ijk[3] = {b[0] * kBlock + t / (kTile * kTile), b[1] * kBlock + (t / kTile) % kTile,
                           b[2] * kBlock + t % kTile};
  if (node_ijk[0] >= s.bx * kBlock || node_ijk[1] >= s.by * kBlock || node_ijk[2] >= s.bz * kBlock) return;
  const long long node = node_index(node_ijk[0], node_ijk[1], node_ijk[2], s);
  const int64_t key = frag.reference[(long long)g * nodes + node];
  if (!key_is_split(key, frag.split_bits)) return;
  const long long ref = key_particle(key);
  if (ref >= bins.n_particles) {  // a key from another particle set: the node is not split
    atomicMin(bounds + 1, (long long)g * nodes + node);
    return;
  }
  float mass = 0.f, momentum[3] = {}, gradient[3] = {}, moment[3] = {};
  for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
    const int q = bins.order[it];
    if (q < 0 || q >= bins.n_particles) {
      atomicMin(bounds + 1, (long long)it);
      continue;
    }
    AxisWeights aw[3];
    stencil_weights(p.x + 3 * (long long)q, geo, aw);
    const int a = node_ijk[0] - aw[0].base, b = node_ijk[1] - aw[1].base, c = node_ijk[2] - aw[2].base;
    if (a < 0 || a > 2 || b < 0 || b > 2 || c < 0 || c > 2) continue;
    split_particle[q] = 1;  // every writer stores the same value
    if (!fragment_side(frag.damage_gradient, q, ref)) continue;  // side A: in P2G's sum already
    atomicOr(reinterpret_cast<unsigned int*>(side_mask + q), side_bit(a, b, c));  // integer OR: order-free
    const float m = p.mass[q];
    const float mv[3] = {m * p.v[3 * q], m * p.v[3 * q + 1], m * p.v[3 * q + 2]};
    float A[9];
    apic_affine(p.C + 9 * (long long)q, p.stress + 9 * (long long)q, m, p.rest_volume[q], dt, geo.inv_dx, A);
    p2g_node_add(aw, a, b, c, m, mv, A, geo.dx, &mass, momentum, gradient, moment);
  }
  if (mass == 0.f) return;  // no particle on side B here (B is zero on entry)
  const long long idx = (long long)(g + frag.n_fields) * nodes + node;
  grid.mass[idx] += mass;
  for (int d = 0; d < 3; ++d) {
    grid.momentum[3 * idx + d] += momentum[d];
    grid.mass_gradient[3 * idx + d] += gradient[d];
    grid.position_moment[3 * idx + d] += moment[d];
  }
  side_b_block[(long long)g * n_blocks + node / kBlockNodes] = 1;  // every writer stores the same value
}

__global__ void clear_kernel(const int32_t* keys, int n_keys, MPMGeometry geo, GridArrays grid) {
  const long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_keys * kBlockNodes) return;
  const long long idx = key_node(keys, t, geo);
  if (idx < 0) return;
  grid.mass[idx] = 0.f;
  for (int d = 0; d < 3; ++d) {
    grid.momentum[3 * idx + d] = 0.f;
    grid.velocity[3 * idx + d] = 0.f;
    grid.mass_gradient[3 * idx + d] = 0.f;
    grid.position_moment[3 * idx + d] = 0.f;
  }
}

}  // namespace

void fragment_reference_cuda(long long n, const float* x, const int32_t* grid_id, const MPMGeometry& geo,
                             float mass_eps, uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                             const DirectionView& directions, float* damage_gradient,
                             int64_t* reference, long long* bounds, void* stream) {
  if (n == 0) return;
  reference_kernel<<<blocks_for(n, kThreads), kThreads, 0, as_stream(stream)>>>(
      n, x, grid_id, geo, mass_eps, split_bits, grid_mass, grid_damage, directions, damage_gradient,
      reference, bounds);
}

void fragment_p2g_cuda(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                       const FragmentView& frag, GridArrays grid, uint8_t* split_particle, int32_t* side_mask,
                       uint8_t* side_b_block, long long* bounds, void* stream) {
  static_assert(kTileNodes <= kThreads, "one thread per tile node");
  for (int color = 0; color < 8; ++color) {
    const int begin = bins.color_start[color], count = bins.color_start[color + 1] - begin;
    if (count > 0)
      partition_color_kernel<<<count, kThreads, 0, as_stream(stream)>>>(bins, begin, p, geo, dt, frag, grid,
                                                                         split_particle, side_mask, side_b_block,
                                                                         bounds);
  }
}

void fragment_merge_cuda(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid, void* stream) {
  if (n_keys == 0) return;
  merge_kernel<<<blocks_for((long long)n_keys * kBlockNodes, kThreads), kThreads, 0, as_stream(stream)>>>(
      keys, n_keys, geo, grid);
}

void fragment_clear_cuda(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid, void* stream) {
  if (n_keys == 0) return;
  clear_kernel<<<blocks_for((long long)n_keys * kBlockNodes, kThreads), kThreads, 0, as_stream(stream)>>>(
      keys, n_keys, geo, grid);
}

}  // namespace fgs
