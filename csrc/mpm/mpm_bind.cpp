// Torch bindings of the MPM kernels: argument checks, memory, and dispatch on the device.
// The kernels themselves (mpm_cpu.cpp, mpm_cuda.cu) never see a torch type.
#include "mpm/mpm_bind.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>
#include <vector>

#include "bound_error.h"
#include "common/constitutive.h"
#include "mpm/mpm_kernels.h"

#ifdef FGS_WITH_CUDA
#include "bind_utils.h"
#endif

namespace fgs {
namespace {

using torch::Tensor;

void check_tensor(const Tensor& t, const char* name, torch::ScalarType dtype, const Tensor& like) {
  TORCH_CHECK(t.scalar_type() == dtype, name, " has dtype ", t.scalar_type(), ", expected ", dtype);
  TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
  TORCH_CHECK(t.device() == like.device(), name, " is on ", t.device(), ", expected ", like.device());
}

MPMGeometry make_geometry(const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                          int64_t n_grids) {
  TORCH_CHECK(lower.size() == 3 && blocks.size() == 3, "lower and blocks must have 3 entries");
  TORCH_CHECK(dx > 0, "dx must be positive");
  MPMGeometry geo;
  for (int d = 0; d < 3; ++d) geo.lower[d] = (float)lower[d];
  geo.dx = (float)dx;
  geo.inv_dx = (float)(1.0 / dx);
  TORCH_CHECK(blocks[0] >= 1 && blocks[1] >= 1 && blocks[2] >= 1 && n_grids >= 1,
              "blocks and n_grids must be positive");
  // Node indices within a grid and (grid, block) keys are int32 in the kernels.
  const int64_t block_count = blocks[0] * blocks[1] * blocks[2];
  if (block_count * kBlockNodes > kMaxInt32Count || block_count * n_grids > kMaxInt32Count)
    throw_bound_error("a grid of ", blocks[0] * kBlock, "x", blocks[1] * kBlock, "x", blocks[2] * kBlock, " nodes (",
                      n_grids, " fields) has more nodes or blocks than the kernels' int32 indices address; "
                      "use a coarser grid");
  geo.shape = GridShape{(int)blocks[0], (int)blocks[1], (int)blocks[2]};
  geo.n_grids = (int)n_grids;
  return geo;
}

// The number of entries of an index list, checked to fit the kernels' int32 counts.
int list_size(const Tensor& t, const char* name) {
  if (t.numel() > kMaxInt32Count)
    throw_bound_error(name, " has ", t.numel(), " entries, more than the kernels' int32 counts hold");
  return (int)t.numel();
}

// Throws where an int32 list (on the CPU) holds an entry outside [0, limit): the kernels index
// grid blocks or particles with it.
void check_index_list(const Tensor& list, int64_t limit, const char* name, const char* what) {
  if (!list.device().is_cpu()) return;
  const int64_t i = first_outside(list.data_ptr<int32_t>(), list.numel(), limit);
  if (i >= 0)
    throw_bound_error(name, "[", i, "] = ", list.data_ptr<int32_t>()[i], " is not a valid ", what, " (0 .. ",
                      limit - 1, ")");
}

// The bins of n particles as bin_particles returns them (order, cell_start, cell_key,
// color_cells, color_start, touched, contact_blocks): their sizes always, and on the CPU every
// index they hold, since the kernels index particles, cells and grid blocks with them. Returns
// color_start on the host (it sizes the launches).
Tensor check_bins(const std::vector<Tensor>& bins, int64_t n, const MPMGeometry& geo, const Tensor& like) {
  TORCH_CHECK(bins.size() == 7, "bins must hold 7 tensors");
  for (const auto& b : bins) check_tensor(b, "bins", torch::kInt32, like);
  if (n > kMaxInt32Count)
    throw_bound_error(n, " particles are more than the kernels' int32 particle indices address");
  const int64_t n_cells = bins[2].numel(), n_keys = (int64_t)geo.n_grids * geo.shape.blocks();
  if (bins[0].numel() != n || bins[1].numel() != n_cells + 1 || bins[3].numel() != n_cells || bins[4].numel() != 9)
    throw_bound_error("the bins do not fit ", n, " particles (order has ", bins[0].numel(), " entries, cell_start ",
                      bins[1].numel(), ", cell_key ", n_cells, ", color_cells ", bins[3].numel(), ", color_start ",
                      bins[4].numel(), " of 9)");
  list_size(bins[5], "touched");
  list_size(bins[6], "contact_blocks");
  const Tensor color_start = bins[4].to(torch::kCPU);
  const int32_t* cs = color_start.data_ptr<int32_t>();
  for (int c = 0; c < 8; ++c)
    if (cs[0] != 0 || cs[c + 1] < cs[c] || cs[8] != n_cells)
      throw_bound_error("color_start is not a partition of the ", n_cells, " cells");
  if (!like.device().is_cpu()) return color_start;  // the CUDA kernels check the indices they read
  const int32_t* start = bins[1].data_ptr<int32_t>();
  if (start[0] != 0 || start[n_cells] != n)
    throw_bound_error("cell_start does not span the ", n, " particles");
  for (int64_t c = 0; c < n_cells; ++c)
    if (start[c + 1] < start[c]) throw_bound_error("cell_start decreases at cell ", c);
  check_index_list(bins[0], n, "order", "particle index");
  check_index_list(bins[2], n_keys, "cell_key", "(grid, block) key");
  check_index_list(bins[3], n_cells, "color_cells", "cell index");
  check_index_list(bins[5], n_keys, "touched", "(grid, block) key");
  check_index_list(bins[6], geo.shape.blocks(), "contact_blocks", "block");
  return color_start;
}

constexpr const char* kMisplaced =
    "does not lie in the grid block it was sorted into (the bins do not match the positions); its stencil would "
    "leave the kernel's window";

// Throws for what a kernel reported out of bounds (BoundReport, or the CUDA kernels' bound slots);
// misplaced_what: what is wrong with the misplaced particle.
void throw_reported(long long misplaced, long long bad_index, const char* kernel,
                    const char* misplaced_what = kMisplaced) {
  if (misplaced >= 0) throw_bound_error(kernel, ": particle ", misplaced, " ", misplaced_what);
  if (bad_index >= 0)
    throw_bound_error(kernel, ": entry ", bad_index, " of an index list (or a reference key) names a particle or "
                      "grid block that does not exist");
}

#ifdef FGS_WITH_CUDA
// Device int64[kBoundSlots] for the CUDA kernels' reports, all INT64_MAX (nothing found).
Tensor bound_slots(const Tensor& like) {
  return torch::full({kBoundSlots}, std::numeric_limits<int64_t>::max(), like.options().dtype(torch::kInt64));
}

void throw_slots(const Tensor& slots, const char* kernel, const char* misplaced_what = kMisplaced) {
  const Tensor host = slots.cpu();
  const int64_t* h = host.data_ptr<int64_t>();
  const int64_t none = std::numeric_limits<int64_t>::max();
  throw_reported(h[0] == none ? -1 : h[0], h[1] == none ? -1 : h[1], kernel, misplaced_what);
}
#endif

void check_grid(const Tensor& t, const char* name, int channels, const MPMGeometry& geo, const Tensor& like) {
  check_tensor(t, name, torch::kFloat32, like);
  TORCH_CHECK(t.numel() == (int64_t)geo.n_grids * geo.shape.nodes() * channels, name, " has ", t.numel(),
              " elements, expected ", (int64_t)geo.n_grids * geo.shape.nodes() * channels);
}

Tensor to_tensor(const std::vector<int32_t>& values) {
  Tensor t = torch::empty({(int64_t)values.size()}, torch::kInt32);
  if (!values.empty()) std::memcpy(t.data_ptr<int32_t>(), values.data(), values.size() * sizeof(int32_t));
  return t;
}

// The grid fields a kernel reads, each checked first (float32, contiguous, on like's device, one
// value or a 3-vector per node of geo's grids); the mass is required, an undefined or absent other
// field becomes nullptr.
GridArrays grid_arrays(const MPMGeometry& geo, const Tensor& like, const Tensor& mass, const Tensor& momentum,
                       const Tensor& velocity, const std::optional<Tensor>& mass_gradient,
                       const std::optional<Tensor>& position_moment) {
  const auto checked = [&](const Tensor& t, const char* name, int channels) -> float* {
    if (!t.defined()) return nullptr;
    check_grid(t, name, channels, geo, like);
    return t.data_ptr<float>();
  };
  GridArrays g;
  TORCH_CHECK(mass.defined(), "grid_mass is required");
  g.mass = checked(mass, "grid_mass", 1);
  g.momentum = checked(momentum, "grid_momentum", 3);
  g.velocity = checked(velocity, "grid_velocity", 3);
  g.mass_gradient = mass_gradient ? checked(*mass_gradient, "grid_mass_gradient", 3) : nullptr;
  g.position_moment = position_moment ? checked(*position_moment, "grid_position_moment", 3) : nullptr;
  return g;
}

// The bins as the kernels read them (checked first: check_bins); color_start must be a host
// tensor (it sizes the launches).
BinsView bins_view(const std::vector<Tensor>& bins, const Tensor& color_start) {
  return BinsView{bins[0].data_ptr<int32_t>(), bins[1].data_ptr<int32_t>(), bins[2].data_ptr<int32_t>(),
                  bins[3].data_ptr<int32_t>(), color_start.data_ptr<int32_t>(), bins[5].data_ptr<int32_t>(),
                  (int)bins[5].numel(), bins[6].data_ptr<int32_t>(), (int)bins[6].numel(),
                  (long long)bins[0].numel(), (int)bins[2].numel()};
}

// Fragment view from (damage_gradient (N,3) float, reference (K*nodes) int64, split_particle (N) uint8).
// Float bits of split_gradient^2: a reference key splits its node where its high word is >= them.
uint32_t split_bits_of(double split_gradient) {
  TORCH_CHECK(split_gradient > 0.0, "split_gradient must be > 0");
  const float threshold = (float)(split_gradient * split_gradient);
  uint32_t bits;
  std::memcpy(&bits, &threshold, sizeof(threshold));
  return bits;
}

FragmentView fragment_view(const std::vector<Tensor>& f, const MPMGeometry& geo, double split_gradient,
                           const Tensor& like) {
  TORCH_CHECK(f.size() == 3 || f.size() == 4,
              "fragments must hold (damage_gradient, reference, split_particle[, side_mask])");
  check_tensor(f[0], "damage_gradient", torch::kFloat32, like);
  check_tensor(f[1], "reference", torch::kInt64, like);
  check_tensor(f[2], "split_particle", torch::kUInt8, like);
  TORCH_CHECK(f[0].numel() == 3 * f[2].numel(), "damage_gradient and split_particle disagree on N");
  TORCH_CHECK(f[1].numel() >= (int64_t)geo.n_grids * geo.shape.nodes(), "reference is too small");
  FragmentView v;
  v.n_fields = geo.n_grids;
  v.split_bits = split_bits_of(split_gradient);
  v.damage_gradient = f[0].data_ptr<float>();
  v.reference = f[1].data_ptr<int64_t>();
  v.split_particle = f[2].data_ptr<uint8_t>();
  v.side_mask = nullptr;
  if (f.size() == 4) {
    check_tensor(f[3], "side_mask", torch::kInt32, like);
    TORCH_CHECK(f[3].numel() == f[2].numel(), "side_mask and split_particle disagree on N");
    v.side_mask = f[3].data_ptr<int32_t>();
  }
  return v;
}

// Damage gradient per particle and reference key per node (fragments, step 2). The bins and x
// are those of P2G; grid_damage and grid_reference as P2G left them. Returns damage_gradient (N,3).
Tensor fragment_reference(const std::vector<Tensor>& bins, const Tensor& x, const Tensor& grid_id,
                          const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                          int64_t n_grids, double mass_eps, double split_gradient, const Tensor& grid_mass,
                          const Tensor& grid_damage, Tensor grid_reference,
                          const std::optional<Tensor>& split_direction, double direction_scale) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  const uint32_t split_bits = split_bits_of(split_gradient);
  TORCH_CHECK(bins.size() == 7, "bins must hold 7 tensors");
  check_tensor(x, "x", torch::kFloat32, x);
  check_tensor(grid_id, "grid_id", torch::kInt32, x);
  // The field tensors may hold 2K grids (fields A and B): only the first K are read here.
  const int64_t k_nodes = (int64_t)geo.n_grids * geo.shape.nodes();
  check_tensor(grid_damage, "grid_damage", torch::kFloat32, x);
  check_tensor(grid_reference, "grid_reference", torch::kInt64, x);
  check_tensor(grid_mass, "grid_mass", torch::kFloat32, x);
  TORCH_CHECK(grid_damage.numel() >= k_nodes && grid_reference.numel() >= k_nodes && grid_mass.numel() >= k_nodes,
              "fragment_reference: grid fields are smaller than the object grids");
  // split_direction: (N, 3) or a view of 3 columns of a (N, S) block (row stride S, unit column stride).
  DirectionView directions{nullptr, 0, (float)direction_scale};
  if (split_direction) {
    const Tensor& d = *split_direction;
    TORCH_CHECK(d.scalar_type() == torch::kFloat32 && d.device() == x.device(),
                "fragment_reference: split_direction must be float32 on the particles' device");
    TORCH_CHECK(d.dim() == 2 && d.size(0) == x.size(0) && d.size(1) == 3 && d.stride(1) == 1 && d.stride(0) >= 3,
                "fragment_reference: split_direction must be (N, 3) with rows of unit column stride");
    directions.direction = d.data_ptr<float>();
    directions.stride = d.stride(0);
  }
  TORCH_CHECK(grid_id.numel() == x.size(0), "fragment_reference: grid_id must have one entry per particle");
  Tensor damage_gradient = torch::empty({x.size(0), 3}, x.options());  // every row is written
  if (x.device().is_cpu()) {
    Tensor color_start = check_bins(bins, x.size(0), geo, x);
    const BinsView view = bins_view(bins, color_start);
    const BoundReport report = fragment_reference_cpu(
        view, x.data_ptr<float>(), geo, (float)mass_eps, split_bits, grid_mass.data_ptr<float>(),
        grid_damage.data_ptr<float>(), directions, damage_gradient.data_ptr<float>(),
        grid_reference.data_ptr<int64_t>());
    throw_reported(report.misplaced, report.bad_reference, "fragment_reference");
    return damage_gradient;
  }
#ifdef FGS_WITH_CUDA
  // Per particle, without the bins: a stencil leaving the grid (or a grid_id out of range) is reported.
  Tensor slots = bound_slots(x);
  fragment_reference_cuda(x.size(0), x.data_ptr<float>(), grid_id.data_ptr<int32_t>(), geo, (float)mass_eps,
                          split_bits, grid_mass.data_ptr<float>(), grid_damage.data_ptr<float>(), directions,
                          damage_gradient.data_ptr<float>(), grid_reference.data_ptr<int64_t>(),
                          reinterpret_cast<long long*>(slots.data_ptr<int64_t>()), current_cuda_stream());
  throw_slots(slots, "fragment_reference", "has a stencil outside the grid (or a grid_id out of range)");
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
  return damage_gradient;
}

// Fragments, step 3: fields A and B at the split nodes. The grid tensors hold 2K grids (A: 0..K-1,
// holding P2G's sums; B: K..2K-1, zero on entry). Returns (split_particle (N) uint8, split_keys (S)
// int32: the (grid, block) keys of the K grids where a split node got side-B mass, ascending,
// side_mask (N) int32: bit 9a+3b+c set where the particle is on side B at its stencil node (a, b, c)).
std::vector<Tensor> fragment_partition(const std::vector<Tensor>& bins, const Tensor& x, const Tensor& v,
                                       const Tensor& C, const Tensor& stress, const Tensor& mass,
                                       const Tensor& rest_volume, const Tensor& grid_id,
                                       const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                                       int64_t n_grids, double dt, const Tensor& damage_gradient,
                                       const Tensor& grid_reference, double split_gradient, Tensor grid_mass,
                                       Tensor grid_momentum, Tensor grid_mass_gradient, Tensor grid_position_moment) {
  TORCH_CHECK(bins.size() == 7, "bins must hold 7 tensors");
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  const MPMGeometry both = make_geometry(lower, dx, blocks, 2 * n_grids);
  const int64_t n = x.size(0);
  for (const Tensor* t : {&x, &v, &C, &stress, &mass, &rest_volume, &damage_gradient})
    check_tensor(*t, "particle array", torch::kFloat32, x);
  check_tensor(grid_id, "grid_id", torch::kInt32, x);
  TORCH_CHECK(v.numel() == 3 * n && C.numel() == 9 * n && stress.numel() == 9 * n && mass.numel() == n &&
                  rest_volume.numel() == n && grid_id.numel() == n && damage_gradient.numel() == 3 * n,
              "fragment_partition: particle arrays have inconsistent sizes");
  GridArrays grid = grid_arrays(both, x, grid_mass, grid_momentum, Tensor(), grid_mass_gradient, grid_position_moment);
  Tensor color_start = check_bins(bins, n, geo, x);
  // The CPU kernel writes every particle's row; the CUDA kernel only those of split particles.
  const bool on_cpu = x.device().is_cpu();
  const auto rows = [&](torch::ScalarType dtype) {
    return on_cpu ? torch::empty({n}, x.options().dtype(dtype)) : torch::zeros({n}, x.options().dtype(dtype));
  };
  Tensor split_particle = rows(torch::kUInt8), side_mask = rows(torch::kInt32);
  // Flags per (grid, block) key of the K grids where field B gets mass. Only touched keys can be
  // flagged, so on the CPU only they are cleared, and the flagged keys are read from them.
  const int64_t k_blocks = (int64_t)geo.n_grids * geo.shape.blocks();
  const int32_t* touched = on_cpu ? bins[5].data_ptr<int32_t>() : nullptr;
  const int64_t n_touched = bins[5].numel();
  Tensor split_block = on_cpu ? torch::empty({k_blocks}, x.options().dtype(torch::kUInt8))
                              : torch::zeros({k_blocks}, x.options().dtype(torch::kUInt8));
  uint8_t* side_b_block = split_block.data_ptr<uint8_t>();
  for (int64_t t = 0; on_cpu && t < n_touched; ++t)
    if (touched[t] < k_blocks) side_b_block[touched[t]] = 0;
  const FragmentView frag = fragment_view({damage_gradient, grid_reference, split_particle}, geo, split_gradient, x);
  ParticleArrays p{x.data_ptr<float>(), v.data_ptr<float>(), C.data_ptr<float>(), stress.data_ptr<float>(),
                   mass.data_ptr<float>(), rest_volume.data_ptr<float>(), grid_id.data_ptr<int32_t>(), nullptr};
  const BinsView view = bins_view(bins, color_start);
  if (on_cpu) {
    const BoundReport report = fragment_p2g_cpu(view, p, geo, (float)dt, frag, grid, split_particle.data_ptr<uint8_t>(),
                                                side_mask.data_ptr<int32_t>(), side_b_block);
    throw_reported(report.misplaced, report.bad_reference, "fragment_partition");
  } else {
#ifdef FGS_WITH_CUDA
    Tensor slots = bound_slots(x);
    fragment_p2g_cuda(view, p, geo, (float)dt, frag, grid, split_particle.data_ptr<uint8_t>(),
                      side_mask.data_ptr<int32_t>(), side_b_block, reinterpret_cast<long long*>(slots.data_ptr<int64_t>()),
                      current_cuda_stream());
    throw_slots(slots, "fragment_partition");
#else
    TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
  }
  Tensor split_keys;  // ascending
  if (on_cpu) {
    std::vector<int32_t> keys;
    for (int64_t t = 0; t < n_touched; ++t)
      if (touched[t] < k_blocks && side_b_block[touched[t]]) keys.push_back(touched[t]);
    split_keys = to_tensor(keys);
    fragment_merge_cpu(split_keys.data_ptr<int32_t>(), (int)split_keys.numel(), geo, grid);
  } else {
    split_keys = torch::nonzero(split_block).flatten().to(torch::kInt32).contiguous();
#ifdef FGS_WITH_CUDA
    fragment_merge_cuda(split_keys.data_ptr<int32_t>(), (int)split_keys.numel(), geo, grid, current_cuda_stream());
#endif
  }
  return {split_particle, split_keys, side_mask};
}

// The bins the field passes use once nodes are split (CPU): (touched followed by the field-B keys,
// the union of the contact blocks and the split blocks, ascending). See fragment_field_blocks_cpu.
std::vector<Tensor> fragment_field_blocks(const Tensor& touched, const Tensor& contact_blocks, const Tensor& split_keys,
                                          int64_t n_blocks, int64_t n_grids) {
  for (const Tensor* t : {&touched, &contact_blocks, &split_keys}) {
    check_tensor(*t, "block list", torch::kInt32, touched);
    TORCH_CHECK(t->device().is_cpu(), "fragment_field_blocks runs on the CPU");
  }
  TORCH_CHECK(n_blocks >= 1 && n_grids >= 1, "fragment_field_blocks: n_blocks and n_grids must be positive");
  if (2 * n_grids * n_blocks > kMaxInt32Count)
    throw_bound_error("fragment_field_blocks: ", 2 * n_grids, " grids of ", n_blocks,
                      " blocks are more (grid, block) keys than int32 holds");
  check_index_list(touched, n_grids * n_blocks, "touched", "(grid, block) key");
  check_index_list(contact_blocks, n_blocks, "contact_blocks", "block");
  check_index_list(split_keys, n_grids * n_blocks, "split_keys", "(grid, block) key");
  std::vector<int32_t> field_touched, field_contact;
  fragment_field_blocks_cpu(touched.data_ptr<int32_t>(), list_size(touched, "touched"),
                            contact_blocks.data_ptr<int32_t>(), list_size(contact_blocks, "contact_blocks"),
                            split_keys.data_ptr<int32_t>(), list_size(split_keys, "split_keys"), (int)n_blocks,
                            (int)n_grids, field_touched, field_contact);
  return {to_tensor(field_touched), to_tensor(field_contact)};
}

// Zeroes every field of the given (grid, block) keys of the 2K-grid tensors (field B after a substep).
void fragment_clear(const Tensor& keys, const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                    int64_t n_grids, Tensor grid_mass, Tensor grid_momentum, Tensor grid_velocity,
                    Tensor grid_mass_gradient, Tensor grid_position_moment) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  check_tensor(keys, "keys", torch::kInt32, grid_mass);
  GridArrays grid = grid_arrays(geo, grid_mass, grid_mass, grid_momentum, grid_velocity, grid_mass_gradient,
                                grid_position_moment);
  const int n_keys = list_size(keys, "keys");
  check_index_list(keys, (int64_t)geo.n_grids * geo.shape.blocks(), "keys", "(grid, block) key");
  if (grid_mass.device().is_cpu()) {
    fragment_clear_cpu(keys.data_ptr<int32_t>(), n_keys, geo, grid);
    return;
  }
#ifdef FGS_WITH_CUDA
  fragment_clear_cuda(keys.data_ptr<int32_t>(), n_keys, geo, grid, current_cuda_stream());
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
}

// Sorts particles into blocks (CPU). Returns (order, cell_start, cell_key, color_cells,
// color_start, touched, contact_blocks) as int32 tensors.
std::vector<Tensor> bin_particles(const Tensor& x, const Tensor& grid_id, const std::vector<double>& lower,
                                  double dx, const std::vector<int64_t>& blocks, int64_t n_grids) {
  TORCH_CHECK(x.device().is_cpu(), "mpm_bin_particles: the compiled binning is CPU only");
  check_tensor(x, "x", torch::kFloat32, x);
  check_tensor(grid_id, "grid_id", torch::kInt32, x);
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3, "x must be (N,3)");
  TORCH_CHECK(grid_id.numel() == x.size(0), "mpm_bin_particles: grid_id must have one entry per particle");
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  if (x.size(0) > kMaxInt32Count)
    throw_bound_error(x.size(0), " particles are more than the kernels' int32 particle indices address");
  ParticleBins bins;
  long long bad = bin_particles_cpu(x.data_ptr<float>(), grid_id.data_ptr<int32_t>(), x.size(0), geo, &bins);
  TORCH_CHECK(bad < 0, "particle ", bad, " is outside the grid (or has a non-finite position)");
  return {to_tensor(bins.order), to_tensor(bins.cell_start), to_tensor(bins.cell_key), to_tensor(bins.color_cells),
          to_tensor(bins.color_start), to_tensor(bins.touched), to_tensor(bins.contact_blocks)};
}

void p2g(const std::vector<Tensor>& bins, const Tensor& x, const Tensor& v, const Tensor& C, const Tensor& stress,
         const Tensor& mass, const Tensor& rest_volume, const Tensor& grid_id, const std::vector<double>& lower,
         double dx, const std::vector<int64_t>& blocks, int64_t n_grids, double dt, Tensor grid_mass,
         Tensor grid_momentum, std::optional<Tensor> grid_mass_gradient, std::optional<Tensor> grid_position_moment,
         std::optional<Tensor> damaged, std::optional<Tensor> grid_damage, std::optional<Tensor> grid_reference) {
  TORCH_CHECK(bins.size() == 7, "bins must hold 7 tensors");
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  const int64_t n = x.size(0);
  check_tensor(x, "x", torch::kFloat32, x);
  check_tensor(v, "v", torch::kFloat32, x);
  check_tensor(C, "C", torch::kFloat32, x);
  check_tensor(stress, "stress", torch::kFloat32, x);
  check_tensor(mass, "mass", torch::kFloat32, x);
  check_tensor(rest_volume, "rest_volume", torch::kFloat32, x);
  check_tensor(grid_id, "grid_id", torch::kInt32, x);
  TORCH_CHECK(v.numel() == 3 * n && C.numel() == 9 * n && stress.numel() == 9 * n && mass.numel() == n &&
                  rest_volume.numel() == n && grid_id.numel() == n,
              "p2g: particle arrays have inconsistent sizes");
  GridArrays grid = grid_arrays(geo, x, grid_mass, grid_momentum, Tensor(), grid_mass_gradient, grid_position_moment);
  Tensor color_start = check_bins(bins, n, geo, x);  // also: on the particles' device
  TORCH_CHECK(damaged.has_value() == grid_damage.has_value() && damaged.has_value() == grid_reference.has_value(),
              "p2g: give damaged, grid_damage and grid_reference together (fragments) or none");
  if (damaged) {
    check_tensor(*damaged, "damaged", torch::kBool, x);
    TORCH_CHECK(damaged->numel() == n, "p2g: damaged has the wrong size");
    check_grid(*grid_damage, "grid_damage", 1, geo, x);
    check_tensor(*grid_reference, "grid_reference", torch::kInt64, x);
    TORCH_CHECK(grid_reference->numel() == (int64_t)geo.n_grids * geo.shape.nodes(), "grid_reference has the wrong size");
  }
  ParticleArrays p{x.data_ptr<float>(), v.data_ptr<float>(), C.data_ptr<float>(), stress.data_ptr<float>(),
                   mass.data_ptr<float>(), rest_volume.data_ptr<float>(), grid_id.data_ptr<int32_t>(),
                   damaged ? reinterpret_cast<const uint8_t*>(damaged->data_ptr<bool>()) : nullptr};
  if (damaged) {
    grid.damage = grid_damage->data_ptr<float>();
    grid.reference = grid_reference->data_ptr<int64_t>();
  }
  const BinsView view = bins_view(bins, color_start);
  if (x.device().is_cpu()) {
    const BoundReport report = p2g_cpu(view, p, geo, (float)dt, grid);
    throw_reported(report.misplaced, report.bad_reference, "p2g");
    return;
  }
#ifdef FGS_WITH_CUDA
  Tensor slots = bound_slots(x);
  p2g_cuda(view, p, geo, (float)dt, grid, reinterpret_cast<long long*>(slots.data_ptr<int64_t>()),
           current_cuda_stream());
  throw_slots(slots, "p2g");
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
}

void grid_update(const Tensor& touched, const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                 int64_t n_grids, double dt, const std::vector<double>& gravity, double mass_eps, Tensor grid_mass,
                 Tensor grid_momentum, Tensor grid_velocity) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  check_tensor(touched, "touched", torch::kInt32, grid_mass);
  GridArrays grid = grid_arrays(geo, grid_mass, grid_mass, grid_momentum, grid_velocity, std::nullopt, std::nullopt);
  TORCH_CHECK(gravity.size() == 3, "gravity must have 3 entries");
  const float g[3] = {(float)gravity[0], (float)gravity[1], (float)gravity[2]};
  const int n_touched = list_size(touched, "touched");
  check_index_list(touched, (int64_t)geo.n_grids * geo.shape.blocks(), "touched", "(grid, block) key");
  if (grid_mass.device().is_cpu()) {
    grid_update_cpu(touched.data_ptr<int32_t>(), n_touched, geo, (float)dt, g, (float)mass_eps, grid);
    return;
  }
#ifdef FGS_WITH_CUDA
  grid_update_cuda(touched.data_ptr<int32_t>(), n_touched, geo, (float)dt, g, (float)mass_eps, grid,
                   current_cuda_stream());
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
}

BoundaryParams make_boundary(int64_t wall_condition, int64_t wall_cells, const std::vector<int64_t>& cells,
                             bool has_ground, double ground_height, double ground_friction, double lower_z, double dx) {
  TORCH_CHECK(cells.size() == 3, "cells must have 3 entries");
  BoundaryParams bc;
  bc.wall_condition = (int)wall_condition;
  bc.wall_cells = (int)wall_cells;
  for (int d = 0; d < 3; ++d) bc.cells[d] = (int)cells[d];
  bc.has_ground = has_ground ? 1 : 0;
  bc.ground_height = (float)ground_height;
  bc.ground_friction = (float)ground_friction;
  bc.lower_z = (float)lower_z;
  bc.dx = (float)dx;
  return bc;
}

void boundaries(const Tensor& touched, const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks,
                int64_t n_grids, int64_t wall_condition, int64_t wall_cells, const std::vector<int64_t>& cells,
                bool has_ground, double ground_height, double ground_friction, double mass_eps, Tensor grid_mass,
                Tensor grid_velocity) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  check_tensor(touched, "touched", torch::kInt32, grid_mass);
  GridArrays grid = grid_arrays(geo, grid_mass, grid_mass, Tensor(), grid_velocity, std::nullopt, std::nullopt);
  const BoundaryParams bc = make_boundary(wall_condition, wall_cells, cells, has_ground, ground_height,
                                          ground_friction, lower[2], dx);
  const int n_touched = list_size(touched, "touched");
  check_index_list(touched, (int64_t)geo.n_grids * geo.shape.blocks(), "touched", "(grid, block) key");
  if (grid_mass.device().is_cpu()) {
    boundaries_cpu(touched.data_ptr<int32_t>(), n_touched, geo, bc, (float)mass_eps, grid);
    return;
  }
#ifdef FGS_WITH_CUDA
  boundaries_cuda(touched.data_ptr<int32_t>(), n_touched, geo, bc, (float)mass_eps, grid, current_cuda_stream());
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
}

void collision(const Tensor& contact_blocks, const std::vector<double>& lower, double dx,
               const std::vector<int64_t>& blocks, int64_t n_grids, double impulse_scale, double friction, double mass_eps,
               double max_gap, double inside, Tensor grid_mass, Tensor grid_velocity, Tensor grid_mass_gradient,
               Tensor grid_position_moment) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  check_tensor(contact_blocks, "contact_blocks", torch::kInt32, grid_mass);
  GridArrays grid = grid_arrays(geo, grid_mass, grid_mass, Tensor(), grid_velocity, grid_mass_gradient,
                                grid_position_moment);
  TORCH_CHECK(friction >= 0.0, "contact friction must be >= 0, got ", friction);
  const ContactParams params{(float)impulse_scale, (float)friction, (float)mass_eps, (float)max_gap, (float)inside};
  const int n_contact = list_size(contact_blocks, "contact_blocks");
  check_index_list(contact_blocks, geo.shape.blocks(), "contact_blocks", "block");
  if (grid_mass.device().is_cpu()) {
    collision_cpu(contact_blocks.data_ptr<int32_t>(), n_contact, geo, params, grid);
    return;
  }
#ifdef FGS_WITH_CUDA
  collision_cuda(contact_blocks.data_ptr<int32_t>(), n_contact, geo, params, grid, current_cuda_stream());
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
}

// Writes the outputs into the given tensors; returns (clamped, first_nonfinite or -1, max |v|).
std::tuple<int64_t, int64_t, double> g2p(
    const Tensor& x, const Tensor& F_E, const Tensor& state, const Tensor& fractured, const Tensor& grid_id,
    const Tensor& material_id, const Tensor& material_table, const Tensor& grid_velocity,
    const std::vector<double>& lower, double dx, const std::vector<int64_t>& blocks, int64_t n_grids, double dt,
    const std::vector<double>& clamp_lower, const std::vector<double>& clamp_upper, Tensor x_out, Tensor v_out,
    Tensor C_out, Tensor F_out, Tensor state_out, Tensor stress_out, Tensor fractured_out,
    std::optional<std::vector<Tensor>> fragments, double split_gradient, std::optional<Tensor> dissipated_out) {
  const MPMGeometry geo = make_geometry(lower, dx, blocks, n_grids);
  const int64_t n = x.size(0);
  check_tensor(x, "x", torch::kFloat32, x);
  check_tensor(F_E, "F_E", torch::kFloat32, x);
  check_tensor(state, "state", torch::kFloat32, x);
  TORCH_CHECK(state.dim() == 2 && state.size(0) == n && state.size(1) >= 1 && state.size(1) <= kMaxStateFields,
              "g2p: state must be (N, S) with 1 <= S <= ", kMaxStateFields);
  check_tensor(fractured, "fractured", torch::kBool, x);
  check_tensor(grid_id, "grid_id", torch::kInt32, x);
  check_tensor(material_id, "material_id", torch::kInt32, x);
  check_tensor(material_table, "material_table", torch::kFloat32, x);
  TORCH_CHECK(material_table.dim() == 2 && material_table.size(1) == kMatFields, "material_table must be (M, ",
              kMatFields, ")");
  FragmentView frag{};
  const FragmentView* frag_ptr = nullptr;
  if (fragments) {  // (damage_gradient, reference, split_particle[, side_mask]): the grids hold fields A and B
    frag = fragment_view(*fragments, geo, split_gradient, x);
    frag_ptr = &frag;
    const MPMGeometry both = make_geometry(lower, dx, blocks, 2 * n_grids);
    check_grid(grid_velocity, "grid_velocity", 3, both, x);
  } else {
    check_grid(grid_velocity, "grid_velocity", 3, geo, x);
  }
  TORCH_CHECK(F_E.numel() == 9 * n && fractured.numel() == n && grid_id.numel() == n &&
                  material_id.numel() == n,
              "g2p: particle arrays have inconsistent sizes");
  const Tensor* outs[] = {&x_out, &v_out, &C_out, &F_out, &state_out, &stress_out};
  const int64_t out_sizes[] = {3 * n, 3 * n, 9 * n, 9 * n, state.numel(), 9 * n};
  for (int i = 0; i < 6; ++i) {
    check_tensor(*outs[i], "g2p output", torch::kFloat32, x);
    TORCH_CHECK(outs[i]->numel() == out_sizes[i], "g2p output has the wrong size");
  }
  check_tensor(fractured_out, "fractured_out", torch::kBool, x);
  TORCH_CHECK(clamp_lower.size() == 3 && clamp_upper.size() == 3, "clamp bounds must have 3 entries");
  G2PInputs in;
  in.x = x.data_ptr<float>();
  in.F_E = F_E.data_ptr<float>();
  in.state = state.data_ptr<float>();
  in.state_stride = (int)state.size(1);
  in.fractured = reinterpret_cast<const uint8_t*>(fractured.data_ptr<bool>());
  in.grid_id = grid_id.data_ptr<int32_t>();
  in.material_id = material_id.data_ptr<int32_t>();
  in.material_table = material_table.data_ptr<float>();
  for (int d = 0; d < 3; ++d) {
    in.clamp_lower[d] = (float)clamp_lower[d];
    in.clamp_upper[d] = (float)clamp_upper[d];
  }
  G2POutputs out{x_out.data_ptr<float>(), v_out.data_ptr<float>(), C_out.data_ptr<float>(), F_out.data_ptr<float>(),
                 state_out.data_ptr<float>(), stress_out.data_ptr<float>(),
                 reinterpret_cast<uint8_t*>(fractured_out.data_ptr<bool>())};
  if (dissipated_out) {
    check_tensor(*dissipated_out, "dissipated_out", torch::kFloat32, x);
    TORCH_CHECK(dissipated_out->numel() == n, "g2p: dissipated_out must have one value per particle");
    out.dissipated = dissipated_out->data_ptr<float>();
  }
  if (x.device().is_cpu()) {
    const G2PStats s = g2p_cpu(n, in, geo, (float)dt, grid_velocity.data_ptr<float>(), out, frag_ptr);
    return {s.clamped, s.first_nonfinite, (double)s.max_speed};
  }
#ifdef FGS_WITH_CUDA
  Tensor stats = torch::tensor({(int64_t)0, std::numeric_limits<int64_t>::max(), (int64_t)0},
                               torch::kInt64).to(x.device());
  g2p_cuda(n, in, geo, (float)dt, grid_velocity.data_ptr<float>(), out,
           reinterpret_cast<long long*>(stats.data_ptr<int64_t>()), current_cuda_stream(), frag_ptr);
  Tensor host = stats.cpu();
  const int64_t* h = host.data_ptr<int64_t>();
  const int32_t speed_bits = (int32_t)h[2];
  float speed_sq;
  std::memcpy(&speed_sq, &speed_bits, sizeof(float));
  return {h[0], h[1] == std::numeric_limits<int64_t>::max() ? -1 : h[1], std::sqrt((double)speed_sq)};
#else
  TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
  return {0, -1, 0.0};
#endif
}

}  // namespace

void register_mpm(pybind11::module& m) {
  m.def("mpm_bin_particles", &bin_particles, "Sort particles into grid blocks (CPU)");
  m.def("mpm_p2g", &p2g, "Particle-to-grid transfer into per-object grids");
  m.def("mpm_grid_update", &grid_update, "Momentum to velocity plus gravity on touched blocks");
  m.def("mpm_boundaries", &boundaries, "Domain walls and ground on touched blocks");
  m.def("mpm_collision", &collision, "Collision-MPM contact impulses between object grids");
  m.def("mpm_g2p", &g2p, "Grid-to-particle transfer, advection and the return map");
  m.def("mpm_fragment_reference", &fragment_reference, "Fragments: damage gradients and node reference keys");
  m.def("mpm_fragment_partition", &fragment_partition, "Fragments: fields A and B at the split nodes");
  m.def("mpm_fragment_field_blocks", &fragment_field_blocks,
        "Fragments: touched blocks with the field-B keys, and contact blocks with the split blocks");
  m.def("mpm_fragment_clear", &fragment_clear, "Fragments: zero the fields of the given grid blocks");
}

}  // namespace fgs
