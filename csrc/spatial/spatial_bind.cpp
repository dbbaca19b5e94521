// Torch binding of the spatial kernels (spatial_kernels.h): checks tensors, builds the hash
// grid (CPU: counting sort in the kernel; CUDA: torch sort of bucket << 32 | index keys and a
// gather of the points into that order) and runs the queries. Python side:
// fracture_gs/fracture/spatial.py.
#include "spatial/spatial_bind.h"

#include <cmath>
#include <optional>

#include "spatial/spatial_kernels.h"

#ifdef FGS_WITH_CUDA
#include "bind_utils.h"
#endif

namespace fgs {
namespace {

using torch::Tensor;
using OptTensor = std::optional<Tensor>;

void check_points(const Tensor& t, const char* name) {
  TORCH_CHECK(t.dim() == 2 && t.size(1) == 3, name, " must have shape (N, 3)");
  TORCH_CHECK(t.scalar_type() == torch::kFloat32 && t.is_contiguous(), name,
              " must be a contiguous float32 tensor");
  TORCH_CHECK(t.size(0) < (int64_t(1) << 31) - 1, name, ": too many points for int32 indices");
}

// The data of an optional (n,) tensor of one dtype on the points' device, or null.
template <typename T>
const T* vector_ptr(const OptTensor& t, int64_t n, const Tensor& like, const char* name,
                    torch::ScalarType type, const char* type_name) {
  if (!t.has_value()) return nullptr;
  TORCH_CHECK(t->dim() == 1 && t->size(0) == n, name, " must have shape (", n, ",)");
  TORCH_CHECK(t->scalar_type() == type && t->is_contiguous(), name, " must be a contiguous ",
              type_name, " tensor");
  TORCH_CHECK(t->device() == like.device(), name, " is on ", t->device(), ", points on ",
              like.device());
  return t->data_ptr<T>();
}

const int32_t* int_ptr(const OptTensor& t, int64_t n, const Tensor& like, const char* name) {
  return vector_ptr<int32_t>(t, n, like, name, torch::kInt32, "int32");
}

const uint8_t* bool_ptr(const OptTensor& t, int64_t n, const Tensor& like, const char* name) {
  return reinterpret_cast<const uint8_t*>(vector_ptr<bool>(t, n, like, name, torch::kBool, "bool"));
}

struct BuiltGrid {
  spatial::HashGrid grid;
  Tensor sorted_point, bucket_start, sorted_xyz, sorted_cell;  // keep the buffers alive
};

BuiltGrid build_grid(const Tensor& points, double cell) {
  TORCH_CHECK(std::isfinite(cell) && cell > 0.0, "radius must be positive and finite, got ", cell);
  const int64_t n = points.size(0);
  int64_t table = 64;
  while (table < 2 * n) table *= 2;
  BuiltGrid out;
  spatial::HashGrid& g = out.grid;
  g.inv_cell = (float)(1.0 / cell);
  g.table_mask = (uint32_t)(table - 1);
  int64_t cells[3] = {1, 1, 1};
  for (int a = 0; a < 3; ++a) g.origin[a] = 0.f;
  if (n > 0) {
    const Tensor lo = std::get<0>(points.min(0)).to(torch::kCPU);
    const Tensor hi = std::get<0>(points.max(0)).to(torch::kCPU);
    TORCH_CHECK(torch::isfinite(lo).all().item<bool>() && torch::isfinite(hi).all().item<bool>(),
                "points contain NaN or Inf");
    for (int a = 0; a < 3; ++a) {
      g.origin[a] = lo[a].item<float>();
      const double span = (hi[a].item<double>() - lo[a].item<double>()) / cell;
      TORCH_CHECK(span < spatial::kMaxCells, "radius ", cell, " is too small for the extent of the "
                  "points (", span, " cells along an axis, at most ", spatial::kMaxCells, ")");
      cells[a] = (int64_t)span + 3;
    }
  }
  g.stride_j = cells[2];
  g.stride_i = cells[1] * cells[2];
  const auto iopt = points.options().dtype(torch::kInt32);
  const auto lopt = points.options().dtype(torch::kInt64);
  out.sorted_point = torch::empty({n}, iopt);
  out.bucket_start = torch::empty({table + 1}, iopt);
  out.sorted_xyz = torch::empty({n, 3}, points.options());
  out.sorted_cell = torch::empty({n}, lopt);
  if (points.is_cuda()) {
#ifdef FGS_WITH_CUDA
    Tensor keys = torch::empty({n}, lopt), cell_keys = torch::empty({n}, lopt);
    spatial::bucket_keys_cuda(g, points.data_ptr<float>(), n, keys.data_ptr<int64_t>(),
                              cell_keys.data_ptr<int64_t>(), current_cuda_stream());
    const Tensor sorted = std::get<0>(keys.sort());
    const Tensor order = sorted.bitwise_and(0xffffffffLL);
    out.sorted_point = order.to(torch::kInt32).contiguous();
    out.sorted_xyz = points.index_select(0, order).contiguous();
    out.sorted_cell = cell_keys.index_select(0, order).contiguous();
    const Tensor bucket = sorted.bitwise_right_shift(32).contiguous();
    const Tensor boundaries = torch::arange(table + 1, lopt);
    out.bucket_start = torch::searchsorted(bucket, boundaries).to(torch::kInt32).contiguous();
    g.sorted_point = out.sorted_point.data_ptr<int32_t>();
    g.bucket_start = out.bucket_start.data_ptr<int32_t>();
    g.sorted_xyz = out.sorted_xyz.data_ptr<float>();
    g.sorted_cell = out.sorted_cell.data_ptr<int64_t>();
#else
    TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
  } else {
    spatial::build_grid_cpu(points.data_ptr<float>(), n, g, out.sorted_point.data_ptr<int32_t>(),
                            out.bucket_start.data_ptr<int32_t>(), out.sorted_xyz.data_ptr<float>(),
                            out.sorted_cell.data_ptr<int64_t>());
  }
  return out;
}

std::tuple<Tensor, Tensor> knn_on_grid(const BuiltGrid& built, const Tensor& points,
                                       const int32_t* pg, const Tensor& queries,
                                       const int32_t* qg, const int32_t* qs, double radius,
                                       int64_t k);

// (index (Q, k) int64, distance (Q, k) float32): see spatial_kernels.h.
std::tuple<Tensor, Tensor> knn_within(const Tensor& points, const OptTensor& point_group,
                                      const Tensor& queries, const OptTensor& query_group,
                                      const OptTensor& query_self, double radius, int64_t k) {
  check_points(points, "points");
  check_points(queries, "queries");
  TORCH_CHECK(queries.device() == points.device(), "queries are on ", queries.device(),
              ", points on ", points.device());
  TORCH_CHECK(k >= 1 && k <= spatial::kMaxNeighbours, "k must be in 1..",
              spatial::kMaxNeighbours, ", got ", k);
  TORCH_CHECK(point_group.has_value() == query_group.has_value(),
              "give both point_group and query_group, or neither");
  const int64_t p = points.size(0), q = queries.size(0);
  const int32_t* pg = int_ptr(point_group, p, points, "point_group");
  const int32_t* qg = int_ptr(query_group, q, points, "query_group");
  const int32_t* qs = int_ptr(query_self, q, points, "query_self");
  const BuiltGrid built = build_grid(points, radius);
  return knn_on_grid(built, points, pg, queries, qg, qs, radius, k);
}

std::tuple<Tensor, Tensor> knn_on_grid(const BuiltGrid& built, const Tensor& points,
                                       const int32_t* pg, const Tensor& queries,
                                       const int32_t* qg, const int32_t* qs, double radius,
                                       int64_t k) {
  const int64_t q = queries.size(0);
  Tensor index = torch::empty({q, k}, points.options().dtype(torch::kInt64));
  Tensor distance = torch::empty({q, k}, points.options());
  if (points.is_cuda()) {
#ifdef FGS_WITH_CUDA
    spatial::knn_within_cuda(built.grid, pg, q, queries.data_ptr<float>(),
                             qg, qs, (float)radius, (int)k, index.data_ptr<int64_t>(),
                             distance.data_ptr<float>(), current_cuda_stream());
#endif
  } else {
    spatial::knn_within_cpu(built.grid, pg, q, queries.data_ptr<float>(),
                            qg, qs, (float)radius, (int)k, index.data_ptr<int64_t>(),
                            distance.data_ptr<float>());
  }
  return {index, distance};
}

// labels (N,) int64: the smallest point index of each point's component.
Tensor component_roots(const Tensor& points, const OptTensor& group, double radius) {
  check_points(points, "points");
  const int64_t n = points.size(0);
  const int32_t* gp = int_ptr(group, n, points, "group");
  const auto iopt = points.options().dtype(torch::kInt32);
  Tensor parent = torch::empty({n}, iopt), labels = torch::empty({n}, iopt);
  const BuiltGrid built = build_grid(points, radius);
  if (points.is_cuda()) {
#ifdef FGS_WITH_CUDA
    spatial::components_cuda(built.grid, gp, n, (float)radius,
                             parent.data_ptr<int32_t>(), labels.data_ptr<int32_t>(),
                             current_cuda_stream());
#endif
  } else {
    spatial::components_cpu(built.grid, gp, n, (float)radius,
                            parent.data_ptr<int32_t>(), labels.data_ptr<int32_t>());
  }
  return labels.to(torch::kInt64);
}

// The small-fragment mask on a built grid (see small_component_mask); hint may be null.
Tensor small_mask_on_grid(const BuiltGrid& built, const Tensor& points, const int32_t* gp,
                          double radius, int64_t min_size, const uint8_t* hint) {
  const int64_t n = points.size(0);
  const auto iopt = points.options().dtype(torch::kInt32);
  Tensor parent = torch::empty({n}, iopt);
  Tensor core = torch::empty({n}, points.options().dtype(torch::kUInt8));
  if (!points.is_cuda()) {  // over the non-core points only (spatial_kernels.h)
    Tensor mask = torch::empty({n}, points.options().dtype(torch::kBool));
    spatial::small_mask_cpu(built.grid, gp, n, (float)radius, (int32_t)min_size, hint,
                            parent.data_ptr<int32_t>(), core.data_ptr<uint8_t>(),
                            reinterpret_cast<uint8_t*>(mask.data_ptr<bool>()));
    return mask;
  }
  Tensor labels = torch::empty({n}, iopt);
#ifdef FGS_WITH_CUDA
  spatial::small_components_cuda(built.grid, gp, n, (float)radius, (int32_t)(min_size - 1), hint,
                                 parent.data_ptr<int32_t>(), core.data_ptr<uint8_t>(),
                                 labels.data_ptr<int32_t>(), current_cuda_stream());
#endif
  const Tensor label = labels.to(torch::kInt64);
  const Tensor is_core = core.to(torch::kBool);
  const Tensor cores = torch::zeros({n}, iopt).index_add_(0, label, core.to(torch::kInt32));
  const Tensor sizes = torch::bincount(label, {}, n);
  return is_core.logical_not()
      .logical_and(cores.index_select(0, label).eq(0))
      .logical_and(sizes.index_select(0, label).lt(min_size));
}

// (N,) bool: points in a component (radius graph, same group) of fewer than min_size points,
// from the core / partial union-find of spatial_kernels.h (no full labelling of large bodies).
// known_core (N,) bool, optional: points known to have at least min_size - 1 neighbours (a hint
// that saves their count; it must not name any other point).
Tensor small_component_mask(const Tensor& points, const OptTensor& group, double radius,
                            int64_t min_size, const OptTensor& known_core) {
  check_points(points, "points");
  TORCH_CHECK(min_size >= 1 && min_size < (int64_t(1) << 31), "min_size must be >= 1, got ",
              min_size);
  const int64_t n = points.size(0);
  const int32_t* gp = int_ptr(group, n, points, "group");
  const uint8_t* hint = bool_ptr(known_core, n, points, "known_core");
  if (min_size == 1 || n == 0) return torch::zeros({n}, points.options().dtype(torch::kBool));
  const BuiltGrid built = build_grid(points, radius);
  return small_mask_on_grid(built, points, gp, radius, min_size, hint);
}

// kept (Q,) int32 of the retained kernels; rows null: query q is point q; full null: every
// count is complete, else only where full[q] (the others stop at stop_at). The kernels check
// every table entry they read (the others are never dereferenced): one that is neither -1 nor
// a point index is an error here. Checking the read entries instead of the whole table spares
// FPGO a min / max pass over a table that was checked when it was built.
Tensor retained_counts(const Tensor& points, const int64_t* rows, const Tensor& table,
                       double radius, const uint8_t* full = nullptr, int32_t stop_at = 0) {
  const int64_t q = table.size(0), n = points.size(0);
  Tensor kept = torch::empty({q}, points.options().dtype(torch::kInt32));
  const int k = (int)table.size(1);
  if (points.is_cuda()) {
#ifdef FGS_WITH_CUDA
    spatial::retained_neighbours_cuda(points.data_ptr<float>(), n, q, rows,
                                      table.data_ptr<int32_t>(), k, (float)radius, full, stop_at,
                                      kept.data_ptr<int32_t>(), current_cuda_stream());
#else
    TORCH_CHECK(false, "fracture_gs._C was built without CUDA kernels");
#endif
  } else {
    spatial::retained_neighbours_cpu(points.data_ptr<float>(), n, q, rows,
                                     table.data_ptr<int32_t>(), k, (float)radius, full, stop_at,
                                     kept.data_ptr<int32_t>());
  }
  if (q > 0)
    TORCH_CHECK(kept.min().item<int32_t>() != spatial::kInvalidTableEntry,
                "table entries must be -1 or index points (0..", n - 1, ")");
  return kept;
}

void check_table(const Tensor& points, const Tensor& table, int64_t rows_expected) {
  TORCH_CHECK(table.dim() == 2 && table.size(0) == rows_expected &&
                  table.scalar_type() == torch::kInt32 && table.is_contiguous(),
              "table must be a contiguous int32 tensor of shape (", rows_expected, ", k)");
  TORCH_CHECK(table.device() == points.device(), "table is on ", table.device(), ", points on ",
              points.device());
}

// kept (Q,) int32: how many of table[q]'s points (int32, -1 padding) lie within radius of point
// rows[q] (see retained_count in hash_grid.h).
Tensor retained_neighbours(const Tensor& points, const Tensor& rows, const Tensor& table,
                           double radius) {
  check_points(points, "points");
  TORCH_CHECK(std::isfinite(radius) && radius > 0.0, "radius must be positive and finite, got ",
              radius);
  TORCH_CHECK(rows.dim() == 1 && rows.scalar_type() == torch::kInt64 && rows.is_contiguous(),
              "rows must be a contiguous int64 tensor of shape (Q,)");
  TORCH_CHECK(rows.device() == points.device(), "rows are on ", rows.device(), ", points on ",
              points.device());
  check_table(points, table, rows.size(0));
  const int64_t n = points.size(0);
  if (rows.numel() > 0)
    TORCH_CHECK(rows.min().item<int64_t>() >= 0 && rows.max().item<int64_t>() < n,
                "rows must index points (0..", n - 1, ")");
  return retained_counts(points, rows.data_ptr<int64_t>(), table, radius);
}

// FPGO's per-object neighbourhood pass on one hash grid (fracture_gs/fracture/spatial.py,
// fracture_neighbourhood): kept = retained rest neighbours; exposed = fractured, no own Gaussian
// and kept < exposure * rest_count;
// hidden = small-fragment mask (kept >= min_size - 1 is the known-core hint); queries = fractured,
// not hidden, and (has_own, exposed or all_interior); neighbours (Q, k) = the k nearest points
// within radius that are neither fractured nor hidden (-1 padding).
std::tuple<Tensor, Tensor, Tensor, Tensor> fracture_neighbourhood(
    const Tensor& points, const Tensor& table, const Tensor& rest_count, double radius,
    int64_t min_size, double exposure, const Tensor& fractured, const Tensor& has_own, int64_t k,
    bool all_interior) {
  check_points(points, "points");
  TORCH_CHECK(std::isfinite(radius) && radius > 0.0, "radius must be positive and finite, got ",
              radius);
  TORCH_CHECK(min_size >= 1 && min_size < (int64_t(1) << 31), "min_size must be >= 1, got ",
              min_size);
  TORCH_CHECK(k >= 1 && k <= spatial::kMaxNeighbours, "k must be in 1..",
              spatial::kMaxNeighbours, ", got ", k);
  const int64_t n = points.size(0);
  check_table(points, table, n);
  TORCH_CHECK(rest_count.dim() == 1 && rest_count.size(0) == n &&
                  rest_count.scalar_type() == torch::kInt32 &&
                  rest_count.device() == points.device(),
              "rest_count must be an int32 tensor of shape (", n, ",) on the points' device");
  bool_ptr(fractured, n, points, "fractured");
  bool_ptr(has_own, n, points, "has_own");
  const auto bopt = points.options().dtype(torch::kBool);
  // exposure matters for fractured points without an own Gaussian only: the others' counts
  // stop at min_size - 1, enough for the known-core hint
  const Tensor interior = fractured.logical_and(has_own.logical_not()).contiguous();
  const Tensor kept = retained_counts(points, nullptr, table, radius,
                                      reinterpret_cast<const uint8_t*>(interior.data_ptr<bool>()),
                                      (int32_t)std::max<int64_t>(min_size - 1, 0));
  const Tensor exposed = interior.logical_and(
      kept.to(torch::kFloat64).lt(rest_count.to(torch::kFloat64) * exposure));
  Tensor hidden = torch::zeros({n}, bopt);
  if (n == 0)
    return {hidden, exposed, torch::empty({0}, points.options().dtype(torch::kInt64)),
            torch::empty({0, k}, points.options().dtype(torch::kInt64))};
  if (min_size > 1) {
    // a point with min_size - 1 retained rest neighbours is core; where the hint names every
    // point, no fragment is small and the grid of all the points is not needed
    const Tensor known_core = kept.ge(min_size - 1).contiguous();
    if (!known_core.all().item<bool>()) {
      const BuiltGrid built = build_grid(points, radius);
      hidden = small_mask_on_grid(built, points, nullptr, radius, min_size,
                                  reinterpret_cast<const uint8_t*>(known_core.data_ptr<bool>()));
    }
  }
  const Tensor visible = hidden.logical_not();
  Tensor drawn = has_own.logical_or(exposed);
  if (all_interior) drawn = torch::ones({n}, bopt);
  const Tensor queries = fractured.logical_and(visible).logical_and(drawn).nonzero().flatten();
  // the candidates get a grid of their own: with the fractured points left out, the k nearest
  // are found in fewer cells (for_each_nearer stops at the k-th distance)
  const Tensor candidates = fractured.logical_not().logical_and(visible).nonzero().flatten();
  Tensor neighbours = torch::full({queries.size(0), k}, -1, candidates.options());
  if (candidates.size(0) > 0 && queries.size(0) > 0) {
    const Tensor candidate_points = points.index_select(0, candidates).contiguous();
    const Tensor query_points = points.index_select(0, queries).contiguous();
    const BuiltGrid candidate_grid = build_grid(candidate_points, radius);
    auto [found, distance] = knn_on_grid(candidate_grid, candidate_points, nullptr, query_points,
                                         nullptr, nullptr, radius, k);
    neighbours = torch::where(found.ge(0), candidates.index_select(0, found.clamp_min(0).flatten())
                                               .view_as(found), found);
  }
  return {hidden, exposed, queries, neighbours};
}

}  // namespace

void register_spatial(pybind11::module& m) {
  m.def("spatial_knn_within", &knn_within,
        "k nearest points within a radius on a uniform hash grid (see fracture_gs/fracture/spatial.py)");
  m.def("spatial_component_roots", &component_roots,
        "Connected components of the radius graph: smallest index of each point's component");
  m.def("spatial_small_component_mask", &small_component_mask,
        "Points in components of the radius graph with fewer than min_size points");
  m.def("spatial_fracture_neighbourhood", &fracture_neighbourhood,
        "FPGO's neighbourhood pass of one object: hidden, exposed, queries, k nearest intact");
  m.def("spatial_retained_neighbours", &retained_neighbours,
        "How many of each point's listed earlier neighbours are still within a radius");
}

}  // namespace fgs
