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

const int32_t* int_ptr(const OptTensor& t, int64_t n, const Tensor& like, const char* name) {
  if (!t.has_value()) return nullptr;
  TORCH_CHECK(t->dim() == 1 && t->size(0) == n, name, " must have shape (", n, ",)");
  TORCH_CHECK(t->scalar_type() == torch::kInt32 && t->is_contiguous(), name,
              " must be a contiguous int32 tensor");
  TORCH_CHECK(t->device() == like.device(), name, " is on ", t->device(), ", points on ",
              like.device());
  return t->data_ptr<int32_t>();
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
  Tensor index = torch::empty({q, k}, points.options().dtype(torch::kInt64));
  Tensor distance = torch::empty({q, k}, points.options());
  const BuiltGrid built = build_grid(points, radius);
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

}  // namespace

void register_spatial(pybind11::module& m) {
  m.def("spatial_knn_within", &knn_within,
        "k nearest points within a radius on a uniform hash grid (see fracture_gs/fracture/spatial.py)");
  m.def("spatial_component_roots", &component_roots,
        "Connected components of the radius graph: smallest index of each point's component");
}

}  // namespace fgs
