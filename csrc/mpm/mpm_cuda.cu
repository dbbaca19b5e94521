// CUDA MPM kernels. Same math as the CPU kernels (csrc/common/*.h); only the loops differ.
//
// P2G is a gather: one thread block per particle cell (a 4x4x4 block of stencil bases) of the
// current colour; each thread owns one node of the 6x6x6 tile the cell's stencils cover and
// sums the contributions of the cell's particles in their sorted order. Cells of one colour
// never share a node, so the block adds its tile to the grid without atomics and the result is
// deterministic.
#include <cuda_runtime.h>

#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

constexpr int kTile = kBlock + 2;               // nodes per tile edge
constexpr int kTileNodes = kTile * kTile * kTile;
constexpr int kP2GThreads = 256;                // >= kTileNodes
constexpr int kChunk = 64;                      // particles staged in shared memory at a time
constexpr int kThreads = 256;

inline cudaStream_t as_stream(void* stream) { return static_cast<cudaStream_t>(stream); }
inline unsigned blocks_for(long long n, int threads) { return (unsigned)((n + threads - 1) / threads); }

struct StagedParticle {
  int base[3];
  float w[3][3];
  float dw[3][3];
  float f[3];
  float mass;
  float damage;  // m D (fragments)
  float mv[3];
  float A[9];
};

// True if a (grid, block) key read from a list lies in the grids (the launchers skip the others).
__device__ inline bool key_in_grids(int key, const MPMGeometry& geo) {
  return key >= 0 && key < geo.n_grids * geo.shape.blocks();
}

__global__ void zero_blocks_kernel(const int32_t* touched, int n_touched, MPMGeometry geo, GridArrays grid,
                                   long long* bounds) {
  long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_touched * kBlockNodes) return;
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
  int key = touched[t / kBlockNodes];
  if (!key_in_grids(key, geo)) {
    atomicMin(bounds + 1, t / kBlockNodes);
    return;
  }
  long long idx = (long long)(key / n_blocks) * nodes + (long long)(key % n_blocks) * kBlockNodes + t % kBlockNodes;
  grid.mass[idx] = 0.f;
  for (int d = 0; d < 3; ++d) grid.momentum[3 * idx + d] = 0.f;
  if (grid.mass_gradient)
    for (int d = 0; d < 3; ++d) grid.mass_gradient[3 * idx + d] = 0.f;
  if (grid.position_moment)
    for (int d = 0; d < 3; ++d) grid.position_moment[3 * idx + d] = 0.f;
  if (grid.damage) grid.damage[idx] = 0.f;
  if (grid.reference) grid.reference[idx] = 0;
}

// The stencil base of a staged entry that P2G skips: no node of the tile matches it.
constexpr int kNoBase = -(1 << 20);

// Stages entry `it` of order (a particle of the cell whose block starts at node `origin`). A
// particle index out of range, or a stencil that does not start in the cell's block (the tile
// holds that block and its upper neighbours only), is reported in bounds and staged so that no
// node takes it.
__device__ inline void stage_particle(const BinsView& bins, int it, const ParticleArrays& p, const MPMGeometry& geo,
                                      float dt, const int origin[3], StagedParticle& sp, long long* bounds) {
  sp.base[0] = sp.base[1] = sp.base[2] = kNoBase;
  const int q = bins.order[it];
  if (q < 0 || q >= bins.n_particles) {
    atomicMin(bounds + 1, (long long)it);
    return;
  }
  AxisWeights aw[3];
  stencil_weights(p.x + 3 * q, geo, aw);
  for (int d = 0; d < 3; ++d)
    if (aw[d].base - origin[d] < 0 || aw[d].base - origin[d] >= kBlock) {
      atomicMin(bounds, (long long)q);
      return;
    }
  for (int d = 0; d < 3; ++d) {
    sp.base[d] = aw[d].base;
    sp.f[d] = aw[d].f;
    for (int a = 0; a < 3; ++a) {
      sp.w[d][a] = aw[d].w[a];
      sp.dw[d][a] = aw[d].dw[a];
    }
  }
  sp.mass = p.mass[q];
  sp.damage = p.damaged ? sp.mass * particle_damage(p.damaged[q]) : 0.f;
  for (int d = 0; d < 3; ++d) sp.mv[d] = sp.mass * p.v[3 * q + d];
  apic_affine(p.C + 9 * q, p.stress + 9 * q, sp.mass, p.rest_volume[q], dt, geo.inv_dx, sp.A);
}

__global__ void p2g_color_kernel(BinsView bins, int color_begin, ParticleArrays p, MPMGeometry geo, float dt,
                                 GridArrays grid, long long* bounds) {
  __shared__ StagedParticle staged[kChunk];
  const GridShape s = geo.shape;
  const int n_blocks = s.blocks();
  const int cell = bins.color_cells[color_begin + blockIdx.x];
  if (cell < 0 || cell >= bins.n_cells || !key_in_grids(bins.cell_key[cell], geo) || bins.cell_start[cell] < 0 ||
      bins.cell_start[cell + 1] > bins.n_particles) {
    if (threadIdx.x == 0) atomicMin(bounds + 1, (long long)(color_begin + blockIdx.x));
    return;
  }
  const int key = bins.cell_key[cell];
  const int g = key / n_blocks, block = key % n_blocks;
  int origin[3];
  block_coords(block, s, origin);
  for (int d = 0; d < 3; ++d) origin[d] *= kBlock;
  const int t = threadIdx.x;
  const int node[3] = {origin[0] + t / (kTile * kTile), origin[1] + (t / kTile) % kTile, origin[2] + t % kTile};
  float mass = 0.f, damage = 0.f, momentum[3] = {0.f, 0.f, 0.f}, gradient[3] = {0.f, 0.f, 0.f},
        moment[3] = {0.f, 0.f, 0.f};
  bool reached = false;
  const int first = bins.cell_start[cell], last = bins.cell_start[cell + 1];
  for (int chunk = first; chunk < last; chunk += kChunk) {
    const int count = min(kChunk, last - chunk);
    if (t < count) stage_particle(bins, chunk + t, p, geo, dt, origin, staged[t], bounds);
    __syncthreads();
    if (t < kTileNodes) {
      for (int i = 0; i < count; ++i) {
        const StagedParticle& sp = staged[i];
        const int a = node[0] - sp.base[0], b = node[1] - sp.base[1], c = node[2] - sp.base[2];
        if (a < 0 || a > 2 || b < 0 || b > 2 || c < 0 || c > 2) continue;
        reached = true;
        const float w = sp.w[0][a] * sp.w[1][b] * sp.w[2][c];
        const float px = ((float)a - sp.f[0]) * geo.dx, py = ((float)b - sp.f[1]) * geo.dx,
                    pz = ((float)c - sp.f[2]) * geo.dx;
        mass += w * sp.mass;
        damage += w * sp.damage;
        moment[0] -= w * sp.mass * px;  // sum w m (x_p - x_i)
        moment[1] -= w * sp.mass * py;
        moment[2] -= w * sp.mass * pz;
        for (int d = 0; d < 3; ++d)
          momentum[d] += w * (sp.mv[d] + sp.A[3 * d] * px + sp.A[3 * d + 1] * py + sp.A[3 * d + 2] * pz);
        gradient[0] += sp.mass * sp.dw[0][a] * sp.w[1][b] * sp.w[2][c];
        gradient[1] += sp.mass * sp.w[0][a] * sp.dw[1][b] * sp.w[2][c];
        gradient[2] += sp.mass * sp.w[0][a] * sp.w[1][b] * sp.dw[2][c];
      }
    }
    __syncthreads();
  }
  if (t >= kTileNodes || !reached) return;
  const long long idx = (long long)g * s.nodes() + node_index(node[0], node[1], node[2], s);
  grid.mass[idx] += mass;
  if (grid.damage) grid.damage[idx] += damage;
  for (int d = 0; d < 3; ++d) grid.momentum[3 * idx + d] += momentum[d];
  if (grid.mass_gradient)
    for (int d = 0; d < 3; ++d) grid.mass_gradient[3 * idx + d] += gradient[d];
  if (grid.position_moment)
    for (int d = 0; d < 3; ++d) grid.position_moment[3 * idx + d] += moment[d];
}

__global__ void grid_update_kernel(const int32_t* touched, int n_touched, MPMGeometry geo, float dt, float gx,
                                   float gy, float gz, float mass_eps, GridArrays grid) {
  long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_touched * kBlockNodes) return;
  const int n_blocks = geo.shape.blocks();
  const int key = touched[t / kBlockNodes];
  if (!key_in_grids(key, geo)) return;
  const long long idx = (long long)(key / n_blocks) * geo.shape.nodes() + (long long)(key % n_blocks) * kBlockNodes +
                        t % kBlockNodes;
  const float gravity[3] = {gx, gy, gz};
  grid_node_velocity(grid.mass[idx], grid.momentum + 3 * idx, dt, gravity, mass_eps, grid.velocity + 3 * idx);
}

__global__ void boundaries_kernel(const int32_t* touched, int n_touched, MPMGeometry geo, BoundaryParams bc,
                                  float mass_eps, GridArrays grid) {
  long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_touched * kBlockNodes) return;
  const int n_blocks = geo.shape.blocks();
  const int key = touched[t / kBlockNodes];
  if (!key_in_grids(key, geo)) return;
  const int block = key % n_blocks, local = (int)(t % kBlockNodes);
  const long long idx = (long long)(key / n_blocks) * geo.shape.nodes() + (long long)block * kBlockNodes + local;
  if (!(grid.mass[idx] > mass_eps)) return;
  int ijk[3];
  node_coords(block * kBlockNodes + local, geo.shape, ijk);
  apply_boundary(ijk, bc, grid.velocity + 3 * idx);
}

__global__ void collision_kernel(const int32_t* contact_blocks, int n_contact, MPMGeometry geo, ContactParams params,
                                 GridArrays grid) {
  long long t = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (t >= (long long)n_contact * kBlockNodes) return;
  const int block = contact_blocks[t / kBlockNodes];
  if (block < 0 || block >= geo.shape.blocks()) return;
  const long long node = (long long)block * kBlockNodes + t % kBlockNodes;
  contact_node(node, geo.shape.nodes(), geo.n_grids, grid.mass, grid.velocity, grid.mass_gradient,
               grid.position_moment, params);
}

// Integer atomics only: a count, a minimum index, and the maximum of a non-negative float through
// its bit pattern (which orders like the value).
// frag.n_fields == 0: no fragments.
__global__ void g2p_kernel(long long n, G2PInputs in, MPMGeometry geo, float dt, const float* grid_velocity,
                           G2POutputs out, long long* stats, FragmentView frag) {
  long long q = blockIdx.x * (long long)blockDim.x + threadIdx.x;
  if (q >= n) return;
  if (g2p_particle_fragments(q, in, geo, dt, grid_velocity, frag.n_fields > 0 ? &frag : nullptr, out))
    atomicAdd(reinterpret_cast<unsigned long long*>(stats), 1ull);
  if (!particle_is_finite(q, out)) {
    atomicMin(stats + 1, q);
    return;
  }
  atomicMax(stats + 2, (long long)__float_as_int(particle_speed_sq(q, out)));
}

}  // namespace

void p2g_cuda(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt, GridArrays grid,
              long long* bounds, void* stream) {
  static_assert(kTileNodes <= kP2GThreads, "one thread per tile node");
  cudaStream_t st = as_stream(stream);
  if (bins.n_touched > 0)
    zero_blocks_kernel<<<blocks_for((long long)bins.n_touched * kBlockNodes, kThreads), kThreads, 0, st>>>(
        bins.touched, bins.n_touched, geo, grid, bounds);
  for (int color = 0; color < 8; ++color) {
    const int begin = bins.color_start[color], count = bins.color_start[color + 1] - begin;
    if (count > 0) p2g_color_kernel<<<count, kP2GThreads, 0, st>>>(bins, begin, p, geo, dt, grid, bounds);
  }
}

void grid_update_cuda(const int32_t* touched, int n_touched, const MPMGeometry& geo, float dt,
                      const float* gravity_host, float mass_eps, GridArrays grid, void* stream) {
  if (n_touched == 0) return;
  grid_update_kernel<<<blocks_for((long long)n_touched * kBlockNodes, kThreads), kThreads, 0, as_stream(stream)>>>(
      touched, n_touched, geo, dt, gravity_host[0], gravity_host[1], gravity_host[2], mass_eps, grid);
}

void boundaries_cuda(const int32_t* touched, int n_touched, const MPMGeometry& geo, const BoundaryParams& bc,
                     float mass_eps, GridArrays grid, void* stream) {
  if (n_touched == 0) return;
  boundaries_kernel<<<blocks_for((long long)n_touched * kBlockNodes, kThreads), kThreads, 0, as_stream(stream)>>>(
      touched, n_touched, geo, bc, mass_eps, grid);
}

void collision_cuda(const int32_t* contact_blocks, int n_contact, const MPMGeometry& geo, const ContactParams& params,
                    GridArrays grid, void* stream) {
  if (n_contact == 0) return;
  collision_kernel<<<blocks_for((long long)n_contact * kBlockNodes, kThreads), kThreads, 0, as_stream(stream)>>>(
      contact_blocks, n_contact, geo, params, grid);
}

void g2p_cuda(long long n, const G2PInputs& in, const MPMGeometry& geo, float dt, const float* grid_velocity,
              G2POutputs out, long long* stats, void* stream, const FragmentView* frag) {
  if (n == 0) return;
  FragmentView off{};
  off.n_fields = 0;
  g2p_kernel<<<blocks_for(n, kThreads), kThreads, 0, as_stream(stream)>>>(n, in, geo, dt, grid_velocity, out, stats,
                                                                           frag ? *frag : off);
}

}  // namespace fgs
