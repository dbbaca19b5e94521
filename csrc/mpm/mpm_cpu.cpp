// CPU (OpenMP) MPM kernels. The per-particle and per-node math comes from the shared headers;
// this file only decides how to loop. P2G processes particle blocks in 8 colours so that blocks
// running at the same time never write the same grid node: no atomics, and the result does not
// depend on the number of threads.
#include <algorithm>
#include <cstring>

#include "mpm/mpm_kernels.h"

namespace fgs {
namespace {

inline int block_color(int block, const GridShape& s) {
  int bk = block % s.bz, bj = (block / s.bz) % s.by, bi = block / (s.by * s.bz);
  return ((bi & 1) << 2) | ((bj & 1) << 1) | (bk & 1);
}

}  // namespace

long long bin_particles_cpu(const float* x, const int32_t* grid_id, long long n,
                            const MPMGeometry& geo, ParticleBins* bins) {
  const GridShape& s = geo.shape;
  const int n_blocks = s.blocks();
  const long long n_keys = (long long)geo.n_grids * n_blocks;
  const int limit[3] = {s.bx * kBlock - 3, s.by * kBlock - 3, s.bz * kBlock - 3};
  std::vector<int32_t> key(n);
  std::vector<uint8_t> reach(n);  // bit d set: the stencil reaches the next block along axis d
  long long bad = -1;
#pragma omp parallel for schedule(static) reduction(max : bad)
  for (long long p = 0; p < n; ++p) {
    int base[3];
    bool ok = grid_id[p] >= 0 && grid_id[p] < geo.n_grids;
    uint8_t r = 0;
    for (int d = 0; d < 3; ++d) {
      float X = (x[3 * p + d] - geo.lower[d]) * geo.inv_dx;
      ok = ok && X >= 0.5f && X < (float)limit[d] + 0.5f;  // also false for NaN
      base[d] = ok ? (int)floorf(X - 0.5f) : 0;
      if ((base[d] & (kBlock - 1)) >= kBlock - 2) r |= (uint8_t)(1 << d);
    }
    if (!ok) {
      bad = std::max(bad, p);
      key[p] = 0;
      continue;
    }
    int block = ((base[0] >> kBlockBits) * s.by + (base[1] >> kBlockBits)) * s.bz +
                (base[2] >> kBlockBits);
    key[p] = grid_id[p] * n_blocks + block;
    reach[p] = r;
  }
  if (bad >= 0) return bad;

  // Stable counting sort of particles by key.
  std::vector<int32_t> count(n_keys + 1, 0);
  for (long long p = 0; p < n; ++p) ++count[key[p] + 1];
  for (long long k = 0; k < n_keys; ++k) count[k + 1] += count[k];
  bins->order.resize(n);
  {
    std::vector<int32_t> cursor(count.begin(), count.end() - 1);
    for (long long p = 0; p < n; ++p) bins->order[cursor[key[p]]++] = (int32_t)p;
  }
  // Non-empty cells, the blocks their stencils touch, and their colours.
  bins->cell_start.clear();
  bins->cell_key.clear();
  std::vector<uint8_t> touched_mark(n_keys, 0);
  for (long long k = 0; k < n_keys; ++k) {
    if (count[k + 1] == count[k]) continue;
    bins->cell_key.push_back((int32_t)k);
    bins->cell_start.push_back(count[k]);
    uint8_t r = 0;
    for (int i = count[k]; i < count[k + 1]; ++i) r |= reach[bins->order[i]];
    const int g = (int)(k / n_blocks), block = (int)(k % n_blocks);
    const int bk = block % s.bz, bj = (block / s.bz) % s.by, bi = block / (s.by * s.bz);
    for (int di = 0; di <= ((r >> 0) & 1); ++di)
      for (int dj = 0; dj <= ((r >> 1) & 1); ++dj)
        for (int dk = 0; dk <= ((r >> 2) & 1); ++dk)
          touched_mark[(long long)g * n_blocks + ((bi + di) * s.by + bj + dj) * s.bz + bk + dk] = 1;
  }
  bins->cell_start.push_back((int32_t)n);
  const int n_cells = (int)bins->cell_key.size();
  bins->color_start.assign(9, 0);
  std::vector<int> colors(n_cells);
  for (int c = 0; c < n_cells; ++c) {
    colors[c] = block_color(bins->cell_key[c] % n_blocks, s);
    ++bins->color_start[colors[c] + 1];
  }
  for (int c = 0; c < 8; ++c) bins->color_start[c + 1] += bins->color_start[c];
  bins->color_cells.resize(n_cells);
  {
    std::vector<int32_t> cursor(bins->color_start.begin(), bins->color_start.end() - 1);
    for (int c = 0; c < n_cells; ++c) bins->color_cells[cursor[colors[c]]++] = c;
  }
  bins->touched.clear();
  for (long long k = 0; k < n_keys; ++k)
    if (touched_mark[k]) bins->touched.push_back((int32_t)k);
  bins->contact_blocks.clear();
  if (geo.n_grids >= 2) {
    for (int b = 0; b < n_blocks; ++b) {
      int grids_here = 0;
      for (int g = 0; g < geo.n_grids; ++g) grids_here += touched_mark[(long long)g * n_blocks + b];
      if (grids_here >= 2) bins->contact_blocks.push_back(b);
    }
  }
  return -1;
}

void p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
             GridArrays grid) {
  const GridShape& s = geo.shape;
  const long long nodes = s.nodes();
  const int n_touched = bins.n_touched;
  const int n_blocks = s.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    long long first = (long long)(bins.touched[t] / n_blocks) * nodes +
                      (long long)(bins.touched[t] % n_blocks) * kBlockNodes;
    std::memset(grid.mass + first, 0, sizeof(float) * kBlockNodes);
    std::memset(grid.momentum + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    if (grid.mass_gradient) std::memset(grid.mass_gradient + 3 * first, 0, sizeof(float) * 3 * kBlockNodes);
    if (grid.volume) std::memset(grid.volume + first, 0, sizeof(float) * kBlockNodes);
  }
  const float dx = geo.dx;
  for (int color = 0; color < 8; ++color) {
    const int c_begin = bins.color_start[color], c_end = bins.color_start[color + 1];
#pragma omp parallel for schedule(dynamic, 2)
    for (int ci = c_begin; ci < c_end; ++ci) {
      const int cell = bins.color_cells[ci];
      const long long grid_offset = (long long)(bins.cell_key[cell] / n_blocks) * nodes;
      // The four fields never overlap; telling the compiler lets it keep values in registers.
      float* FGS_RESTRICT mass = grid.mass + grid_offset;
      float* FGS_RESTRICT momentum = grid.momentum + 3 * grid_offset;
      float* FGS_RESTRICT gradient = grid.mass_gradient ? grid.mass_gradient + 3 * grid_offset : nullptr;
      float* FGS_RESTRICT volume = grid.volume ? grid.volume + grid_offset : nullptr;
      for (int it = bins.cell_start[cell]; it < bins.cell_start[cell + 1]; ++it) {
        const int q = bins.order[it];
        AxisWeights aw[3];
        for (int d = 0; d < 3; ++d) aw[d] = axis_weights((p.x[3 * q + d] - geo.lower[d]) * geo.inv_dx, geo.inv_dx);
        const float m = p.mass[q];
        const float V = p.rest_volume[q];
        float A[9];
        apic_affine(p.C + 9 * q, p.stress + 9 * q, m, p.rest_volume[q], dt, geo.inv_dx, A);
        const float mv[3] = {m * p.v[3 * q], m * p.v[3 * q + 1], m * p.v[3 * q + 2]};
        int ox[3], oy[3], oz[3];
        float px[3], py[3], pz[3];  // node offsets from the particle, world units
        for (int a = 0; a < 3; ++a) {
          ox[a] = offset_x(aw[0].base + a, s);
          oy[a] = offset_y(aw[1].base + a, s);
          oz[a] = offset_z(aw[2].base + a, s);
          px[a] = ((float)a - aw[0].f) * dx;
          py[a] = ((float)a - aw[1].f) * dx;
          pz[a] = ((float)a - aw[2].f) * dx;
        }
        for (int a = 0; a < 3; ++a) {
          for (int b = 0; b < 3; ++b) {
            const float wab = aw[0].w[a] * aw[1].w[b];
            for (int c = 0; c < 3; ++c) {
              const float w = wab * aw[2].w[c];
              const int idx = ox[a] + oy[b] + oz[c];
              mass[idx] += w * m;
              for (int d = 0; d < 3; ++d)
                momentum[3 * idx + d] += w * (mv[d] + A[3 * d] * px[a] + A[3 * d + 1] * py[b] + A[3 * d + 2] * pz[c]);
              if (volume) volume[idx] += w * V;
              if (gradient) {
                gradient[3 * idx + 0] += m * aw[0].dw[a] * aw[1].w[b] * aw[2].w[c];
                gradient[3 * idx + 1] += m * aw[0].w[a] * aw[1].dw[b] * aw[2].w[c];
                gradient[3 * idx + 2] += m * aw[0].w[a] * aw[1].w[b] * aw[2].dw[c];
              }
            }
          }
        }
      }
    }
  }
}

void grid_update_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo, float dt,
                     const float* gravity, float mass_eps, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    const long long first = (long long)(touched[t] / n_blocks) * nodes + (long long)(touched[t] % n_blocks) * kBlockNodes;
    for (long long idx = first; idx < first + kBlockNodes; ++idx) {
      grid_node_velocity(grid.mass[idx], grid.momentum + 3 * idx, dt, gravity, mass_eps, grid.velocity + 3 * idx);
    }
  }
}

void boundaries_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo,
                    const BoundaryParams& bc, float mass_eps, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
  const int n_blocks = geo.shape.blocks();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_touched; ++t) {
    const int block = touched[t] % n_blocks;
    const long long first = (long long)(touched[t] / n_blocks) * nodes + (long long)block * kBlockNodes;
    for (int local = 0; local < kBlockNodes; ++local) {
      const long long idx = first + local;
      if (!(grid.mass[idx] > mass_eps)) continue;
      int ijk[3];
      node_coords(block * kBlockNodes + local, geo.shape, ijk);
      apply_boundary(ijk, bc, grid.velocity + 3 * idx);
    }
  }
}

void collision_cpu(const int32_t* contact_blocks, int n_contact, const MPMGeometry& geo,
                   float strength, float friction, float mass_eps, float min_volume, GridArrays grid) {
  const long long nodes = geo.shape.nodes();
#pragma omp parallel for schedule(static)
  for (int t = 0; t < n_contact; ++t) {
    const long long first = (long long)contact_blocks[t] * kBlockNodes;
    for (long long node = first; node < first + kBlockNodes; ++node)
      contact_node(node, nodes, geo.n_grids, grid.mass, grid.velocity, grid.mass_gradient, grid.volume, strength,
                   friction, mass_eps, min_volume);
  }
}

G2PStats g2p_cpu(long long n, const G2PInputs& in, const MPMGeometry& geo, float dt,
                 const float* grid_velocity, G2POutputs out) {
  long long clamped = 0, first_bad = n;
  float max_speed_sq = 0.f;
#pragma omp parallel for schedule(static) reduction(+ : clamped) reduction(min : first_bad) \
    reduction(max : max_speed_sq)
  for (long long q = 0; q < n; ++q) {
    clamped += g2p_particle(q, in, geo, dt, grid_velocity, out) ? 1 : 0;
    if (!particle_is_finite(q, out)) {
      first_bad = q < first_bad ? q : first_bad;
      continue;
    }
    const float speed_sq = particle_speed_sq(q, out);
    max_speed_sq = speed_sq > max_speed_sq ? speed_sq : max_speed_sq;
  }
  return G2PStats{clamped, first_bad < n ? first_bad : -1, sqrtf(max_speed_sq)};
}

}  // namespace fgs
