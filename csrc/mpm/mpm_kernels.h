// Framework-free MPM kernels (raw pointers). The CPU versions live in mpm_cpu.cpp (OpenMP), the
// CUDA launchers in mpm_cuda.cu; the torch binding (mpm_bind.cpp) allocates memory and
// dispatches on the device. All matrices are row-major float[9].
#pragma once
#include <cstdint>
#include <vector>

#include "common/mpm_fragments.h"
#include "common/mpm_transfer.h"

namespace fgs {

// Particles sorted into 4x4x4 blocks of their stencil base node, one list per (grid, block).
// "cells" are the non-empty (grid, block) pairs; "touched" blocks are the ones some stencil
// reaches (a cell block and its 7 upper neighbours), per grid; "contact" blocks are block ids
// touched by two or more grids.
struct ParticleBins {
  std::vector<int32_t> order;             // (N) particle indices sorted by (grid, block), stable
  std::vector<int32_t> cell_start;        // (P+1) ranges into order
  std::vector<int32_t> cell_key;          // (P) grid * n_blocks + block
  std::vector<int32_t> color_cells;       // (P) cell indices grouped by block parity colour
  std::vector<int32_t> color_start;       // (9) ranges into color_cells
  std::vector<int32_t> touched;           // (T) grid * n_blocks + block, ascending
  std::vector<int32_t> contact_blocks;    // (Q) block ids touched by >= 2 grids, ascending
};

// Read-only view of the bins for the P2G launch (device pointers for CUDA, except color_start
// which is always on the host because it sizes the launches). The binding checks the bins'
// sizes and, on the CPU, every index they hold (check_bins in mpm_bind.cpp); the CUDA kernels
// check the indices they read.
struct BinsView {
  const int32_t* order;
  const int32_t* cell_start;
  const int32_t* cell_key;
  const int32_t* color_cells;
  const int32_t* color_start;
  const int32_t* touched;
  int n_touched;
  const int32_t* contact_blocks;  // host pointer on the CPU path (P2G reads it there only)
  int n_contact;
  long long n_particles;  // N: the entries of order, and the particle arrays' rows
  int n_cells;            // P: cells (entries of cell_key and color_cells)
};

// What the CUDA P2G-side kernels found out of bounds (device int64[2], both initialised by the
// caller to INT64_MAX; atomicMin keeps the first): [0] the smallest particle index whose stencil
// does not start in its cell's block (or, for the fragment reference pass, leaves the grid),
// [1] the smallest position in order / the key lists holding an index out of range.
constexpr int kBoundSlots = 2;

struct ParticleArrays {  // inputs of P2G, N rows each
  const float* x;
  const float* v;
  const float* C;
  const float* stress;       // Kirchhoff stress tau
  const float* mass;
  const float* rest_volume;
  const int32_t* grid_id;
  const uint8_t* damaged;  // damage flags of the fragment partition (D_p = 1 where set), or nullptr
};

struct GridArrays {  // n_grids * nodes rows each
  float* mass;
  float* momentum;       // (.., 3)
  float* velocity;       // (.., 3)
  float* mass_gradient;  // (.., 3) or nullptr when no contact normals are needed (CPU P2G: contact blocks only)
  float* position_moment;  // (.., 3) sum w m (x_p - x_i), or nullptr (only for contact; CPU P2G: contact blocks only)
  float* damage = nullptr;       // (K * nodes) sum w m D (fragments), or nullptr
  int64_t* reference = nullptr;  // (K * nodes) fragment reference keys (zeroed by P2G), or nullptr
};

// What a CPU kernel found out of bounds, -1 where nothing: the smallest particle index whose
// stencil does not start in the block of the cell it was sorted into (P2G's windows hold that
// block and its upper neighbours only; the particle is skipped), and the smallest node whose
// reference key names a particle index >= N (the node is treated as not split).
struct BoundReport {
  long long misplaced = -1;
  long long bad_reference = -1;
};

// Returns -1 on success or the index of a particle whose stencil leaves the grid.
long long bin_particles_cpu(const float* x, const int32_t* grid_id, long long n,
                            const MPMGeometry& geo, ParticleBins* bins);
BoundReport p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                    GridArrays grid);
void grid_update_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo, float dt,
                     const float* gravity, float mass_eps, GridArrays grid);
void boundaries_cpu(const int32_t* touched, int n_touched, const MPMGeometry& geo,
                    const BoundaryParams& bc, float mass_eps, GridArrays grid);
// Contact impulses at the nodes of the contact blocks (contact_node, csrc/common/mpm_math.h).
void collision_cpu(const int32_t* contact_blocks, int n_contact, const MPMGeometry& geo, const ContactParams& params,
                   GridArrays grid);
// frag: nullptr without fragments; else particles with split_particle set gather per-node fields.
G2PStats g2p_cpu(long long n, const G2PInputs& in, const MPMGeometry& geo, float dt,
                 const float* grid_velocity, G2POutputs out, const FragmentView* frag = nullptr);

// Fragments (csrc/common/mpm_fragments.h). geo.n_grids = K object grids; the grid arrays hold 2K.
// Damage gradient of every particle and, at every node its stencil reaches, the reference key
// (reference must be zero on entry: P2G clears it on touched blocks). Only keys that split a node
// (|grad D|^2 bits >= split_bits) are stored: the others could never be read. directions: particles
// with a non-zero split direction take it, scaled, as their vector (apply_split_direction).
BoundReport fragment_reference_cpu(const BinsView& bins, const float* x, const MPMGeometry& geo, float mass_eps,
                                   uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                                   const DirectionView& directions, float* damage_gradient, int64_t* reference);
// Sums field B (grid K + g) at the split nodes from the particles on side B there (field A keeps
// P2G's sum of all particles); split_particle[q] = 1 if q's stencil reaches a split node, else 0,
// side_mask[q] the bits (side_bit) of its stencil nodes where it is on side B (both written for
// every particle); side_b_block[key] = 1 for the (grid, block) keys of the K grids where field B
// got mass (zero it before).
BoundReport fragment_p2g_cpu(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                             const FragmentView& frag, GridArrays grid, uint8_t* split_particle, int32_t* side_mask,
                             uint8_t* side_b_block);
// After fragment_p2g: field A of every node with side-B mass in the given (grid, block) keys
// becomes P2G's sum minus side B's share (split_node_fields, csrc/common/mpm_fragments.h).
void fragment_merge_cpu(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid);
// The blocks the field passes visit once nodes are split: touched (ascending) followed by the
// field-B keys split_keys + K * n_blocks, and the union of contact_blocks and the blocks of
// split_keys (ascending), where fields A and B meet through the contact pass.
void fragment_field_blocks_cpu(const int32_t* touched, int n_touched, const int32_t* contact_blocks, int n_contact,
                               const int32_t* split_keys, int n_split, int n_blocks, int n_grids,
                               std::vector<int32_t>& field_touched, std::vector<int32_t>& field_contact);
// Zeroes every field of the given (grid, block) keys (field B after the substep).
void fragment_clear_cpu(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid);

#ifdef FGS_WITH_CUDA
// CUDA launchers: device pointers, stream is a cudaStream_t. bounds: device int64[kBoundSlots]
// (see kBoundSlots). Launchers over key lists skip an entry outside the grids.
void p2g_cuda(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
              GridArrays grid, long long* bounds, void* stream);
void grid_update_cuda(const int32_t* touched, int n_touched, const MPMGeometry& geo, float dt,
                      const float* gravity_host, float mass_eps, GridArrays grid, void* stream);
void boundaries_cuda(const int32_t* touched, int n_touched, const MPMGeometry& geo,
                     const BoundaryParams& bc, float mass_eps, GridArrays grid, void* stream);
void collision_cuda(const int32_t* contact_blocks, int n_contact, const MPMGeometry& geo,
                    const ContactParams& params, GridArrays grid, void* stream);
// stats: device int64[3] = {clamped, first_nonfinite, bits of max |v|^2}, initialised by the
// caller to {0, INT64_MAX, 0}.
void g2p_cuda(long long n, const G2PInputs& in, const MPMGeometry& geo, float dt,
              const float* grid_velocity, G2POutputs out, long long* stats, void* stream,
              const FragmentView* frag = nullptr);
void fragment_reference_cuda(long long n, const float* x, const int32_t* grid_id, const MPMGeometry& geo,
                             float mass_eps, uint32_t split_bits, const float* grid_mass, const float* grid_damage,
                             const DirectionView& directions, float* damage_gradient,
                             int64_t* reference, long long* bounds, void* stream);
void fragment_p2g_cuda(const BinsView& bins, const ParticleArrays& p, const MPMGeometry& geo, float dt,
                       const FragmentView& frag, GridArrays grid, uint8_t* split_particle, int32_t* side_mask,
                       uint8_t* side_b_block, long long* bounds, void* stream);
void fragment_merge_cuda(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid, void* stream);
void fragment_clear_cuda(const int32_t* keys, int n_keys, const MPMGeometry& geo, GridArrays grid, void* stream);
#endif

}  // namespace fgs
