// torch <-> raw-pointer glue for the material kernels (csrc/mpm/material_kernels.*).
#include "mpm/material_bind.h"

#include <string>
#include <tuple>
#include <vector>

#include "common/constitutive.h"
#include "mpm/material_kernels.h"

#ifdef FGS_WITH_CUDA
#include <c10/cuda/CUDAException.h>
#include <c10/cuda/CUDAGuard.h>
#include "bind_utils.h"
#endif

namespace fgs {

namespace {

void check_float_tensor(const torch::Tensor& t, const char* name) {
  TORCH_CHECK_TYPE(t.scalar_type() == torch::kFloat32, name, " must be float32, got ", t.scalar_type());
}

void check_deformation(const torch::Tensor& F, const char* name) {
  TORCH_CHECK_VALUE(F.dim() == 3 && F.size(1) == 3 && F.size(2) == 3, name,
                    " must have shape (N, 3, 3), got ", F.sizes());
  check_float_tensor(F, name);
}

void check_table(const torch::Tensor& table, const torch::Tensor& material_id, int64_t n,
                 const torch::Device& device) {
  TORCH_CHECK_VALUE(table.dim() == 2 && table.size(1) == kMatFields,
                    "material_table must have shape (M, ", static_cast<int>(kMatFields), "), got ",
                    table.sizes());
  check_float_tensor(table, "material_table");
  TORCH_CHECK_VALUE(material_id.dim() == 1 && material_id.size(0) == n,
                    "material_id must have shape (", n, ",), got ", material_id.sizes());
  TORCH_CHECK_TYPE(material_id.scalar_type() == torch::kInt32, "material_id must be int32, got ",
                   material_id.scalar_type());
  TORCH_CHECK_VALUE(table.device() == device && material_id.device() == device,
                    "material_table and material_id must be on ", device);
}


// A material state block (n, stride) on `device`, 1 <= stride <= kMaxStateFields (contiguous copy); an
// (n,) tensor is a block of one field.
torch::Tensor state_block(const torch::Tensor& t, int64_t n, const torch::Device& device) {
  TORCH_CHECK_VALUE((t.dim() == 1 && t.size(0) == n) ||
                        (t.dim() == 2 && t.size(0) == n && t.size(1) >= 1 && t.size(1) <= kMaxStateFields),
                    "state must have shape (", n, ",) or (", n, ", S) with 1 <= S <= ",
                    static_cast<int>(kMaxStateFields), ", got ", t.sizes());
  check_float_tensor(t, "state");
  TORCH_CHECK_VALUE(t.device() == device, "state must be on ", device);
  return t.contiguous();
}

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor> constitutive_update_op(
    const torch::Tensor& F_trial, const torch::Tensor& state, const torch::Tensor& material_table,
    const torch::Tensor& material_id) {
  check_deformation(F_trial, "F_trial");
  const int64_t n = F_trial.size(0);
  const auto state_in = state_block(state, n, F_trial.device());
  const int stride = state_in.dim() == 1 ? 1 : static_cast<int>(state_in.size(1));
  check_table(material_table, material_id, n, F_trial.device());

  const auto F_in = F_trial.contiguous();
  const auto table = material_table.contiguous();
  const auto ids = material_id.contiguous();
  auto F_out = torch::empty_like(F_in);
  auto state_out = torch::empty_like(state_in);
  auto tau = torch::empty_like(F_in);
  auto dissipated = torch::empty({n}, F_in.options());
  if (F_in.is_cuda()) {
#ifdef FGS_WITH_CUDA
    const c10::cuda::CUDAGuard guard(F_in.device());
    constitutive_update_cuda(n, F_in.data_ptr<float>(), state_in.data_ptr<float>(), stride, table.data_ptr<float>(),
                             table.size(0), ids.data_ptr<int32_t>(), F_out.data_ptr<float>(),
                             state_out.data_ptr<float>(), tau.data_ptr<float>(), dissipated.data_ptr<float>(),
                             current_cuda_stream());
    C10_CUDA_KERNEL_LAUNCH_CHECK();
#else
    TORCH_CHECK(false, "constitutive_update: fracture_gs._C was built without CUDA");
#endif
  } else {
    const int64_t invalid = constitutive_update_cpu(
        n, F_in.data_ptr<float>(), state_in.data_ptr<float>(), stride, table.data_ptr<float>(), table.size(0),
        ids.data_ptr<int32_t>(), F_out.data_ptr<float>(), state_out.data_ptr<float>(), tau.data_ptr<float>(),
        dissipated.data_ptr<float>());
    TORCH_CHECK_VALUE(invalid == 0, "material_id: ", invalid, " particles have an id outside [0, ",
                      table.size(0), ")");
  }
  return {F_out, state_out, tau, dissipated};
}

torch::Tensor elastic_energy_op(const torch::Tensor& F_E, const torch::Tensor& state,
                                const torch::Tensor& material_table, const torch::Tensor& material_id) {
  check_deformation(F_E, "F_E");
  const int64_t n = F_E.size(0);
  check_table(material_table, material_id, n, F_E.device());
  const auto state_in = state_block(state, n, F_E.device());
  const int stride = state_in.dim() == 1 ? 1 : static_cast<int>(state_in.size(1));
  const auto F_in = F_E.contiguous();
  const auto table = material_table.contiguous();
  const auto ids = material_id.contiguous();
  auto psi = torch::empty({n}, F_in.options());
  if (F_in.is_cuda()) {
#ifdef FGS_WITH_CUDA
    const c10::cuda::CUDAGuard guard(F_in.device());
    elastic_energy_cuda(n, F_in.data_ptr<float>(), state_in.data_ptr<float>(), stride, table.data_ptr<float>(),
                        table.size(0), ids.data_ptr<int32_t>(), psi.data_ptr<float>(), current_cuda_stream());
    C10_CUDA_KERNEL_LAUNCH_CHECK();
#else
    TORCH_CHECK(false, "elastic_energy: fracture_gs._C was built without CUDA");
#endif
  } else {
    const int64_t invalid = elastic_energy_cpu(n, F_in.data_ptr<float>(), state_in.data_ptr<float>(), stride,
                                               table.data_ptr<float>(), table.size(0), ids.data_ptr<int32_t>(),
                                               psi.data_ptr<float>());
    TORCH_CHECK_VALUE(invalid == 0, "material_id: ", invalid, " particles have an id outside [0, ",
                      table.size(0), ")");
  }
  return psi;
}

// The models the kernels know (csrc/common/material_registry.h), for the Python side to check its
// classes against: one dict per model with its code, name, parameter columns and state fields.
pybind11::list material_models() {
  pybind11::list models;
  MaterialModels::for_each([&](auto model) {
    using Model = decltype(model);
    pybind11::list parameters, state;
    for (const char* name : Model::kParameters) parameters.append(std::string(name));
    for (const char* name : Model::kState) state.append(std::string(name));
    pybind11::dict entry;
    entry["code"] = Model::kCode;
    entry["name"] = std::string(Model::kName);
    entry["parameters"] = parameters;
    entry["state"] = state;
    models.append(entry);
  });
  return models;
}

std::tuple<torch::Tensor, torch::Tensor, torch::Tensor> svd3_batch_op(const torch::Tensor& F) {
  check_deformation(F, "F");
  const int64_t n = F.size(0);
  const auto F_in = F.contiguous();
  auto U = torch::empty_like(F_in);
  auto V = torch::empty_like(F_in);
  auto sigma = torch::empty({n, 3}, F_in.options());
  if (F_in.is_cuda()) {
#ifdef FGS_WITH_CUDA
    const c10::cuda::CUDAGuard guard(F_in.device());
    svd3_batch_cuda(n, F_in.data_ptr<float>(), U.data_ptr<float>(), sigma.data_ptr<float>(),
                    V.data_ptr<float>(), current_cuda_stream());
    C10_CUDA_KERNEL_LAUNCH_CHECK();
#else
    TORCH_CHECK(false, "svd3_batch: fracture_gs._C was built without CUDA");
#endif
  } else {
    svd3_batch_cpu(n, F_in.data_ptr<float>(), U.data_ptr<float>(), sigma.data_ptr<float>(),
                   V.data_ptr<float>());
  }
  return {U, sigma, V};
}

// split_direction_step on the rows of `state` (N, S) float32 (changed in place) where mine (N,) bool is set.
void advance_split_directions_op(torch::Tensor& state, const torch::Tensor& trigger_old, const torch::Tensor& C,
                                 const torch::Tensor& F_E, const torch::Tensor& mine, int64_t first,
                                 int64_t trigger, double start, double dt, const std::vector<double>& orientation) {
  TORCH_CHECK_VALUE(state.dim() == 2, "state must have shape (N, S), got ", state.sizes());
  check_float_tensor(state, "state");
  TORCH_CHECK_VALUE(state.is_contiguous(), "state must be contiguous (it is changed in place)");
  const int64_t n = state.size(0), stride = state.size(1);
  TORCH_CHECK_VALUE(first >= 0 && first + 3 <= stride, "first: columns [", first, ", ", first + 3,
                    ") are not all in a state of ", stride, " columns");
  TORCH_CHECK_VALUE(trigger >= 0 && trigger < stride, "trigger: column ", trigger, " is not in a state of ",
                    stride, " columns");
  TORCH_CHECK_VALUE(orientation.size() == 3, "orientation must have 3 components");
  check_deformation(C, "C");
  check_deformation(F_E, "F_E");
  TORCH_CHECK_VALUE(C.size(0) == n && F_E.size(0) == n, "C and F_E must have one row per state row");
  TORCH_CHECK_VALUE(trigger_old.dim() == 1 && trigger_old.size(0) == n, "trigger_old must have shape (", n,
                    ",), got ", trigger_old.sizes());
  check_float_tensor(trigger_old, "trigger_old");
  TORCH_CHECK_VALUE(mine.dim() == 1 && mine.size(0) == n, "mine must have shape (", n, ",), got ", mine.sizes());
  TORCH_CHECK_TYPE(mine.scalar_type() == torch::kBool, "mine must be bool, got ", mine.scalar_type());
  const auto& device = state.device();
  TORCH_CHECK_VALUE(trigger_old.device() == device && C.device() == device && F_E.device() == device &&
                        mine.device() == device,
                    "state, trigger_old, C, F_E and mine must be on one device");
  const SplitDirectionParams params{static_cast<int>(first), static_cast<int>(trigger), static_cast<float>(start),
                                    static_cast<float>(dt),
                                    {static_cast<float>(orientation[0]), static_cast<float>(orientation[1]),
                                     static_cast<float>(orientation[2])}};
  const auto old_in = trigger_old.contiguous();
  const auto C_in = C.contiguous();
  const auto F_in = F_E.contiguous();
  const auto mine_in = mine.contiguous();
  const auto* mine_ptr = reinterpret_cast<const uint8_t*>(mine_in.data_ptr<bool>());
  if (state.is_cuda()) {
#ifdef FGS_WITH_CUDA
    const c10::cuda::CUDAGuard guard(device);
    advance_split_directions_cuda(n, state.data_ptr<float>(), static_cast<int>(stride), old_in.data_ptr<float>(),
                                  C_in.data_ptr<float>(), F_in.data_ptr<float>(), mine_ptr, params,
                                  current_cuda_stream());
    C10_CUDA_KERNEL_LAUNCH_CHECK();
#else
    TORCH_CHECK(false, "advance_split_directions: fracture_gs._C was built without CUDA");
#endif
  } else {
    advance_split_directions_cpu(n, state.data_ptr<float>(), static_cast<int>(stride), old_in.data_ptr<float>(),
                                 C_in.data_ptr<float>(), F_in.data_ptr<float>(), mine_ptr, params);
  }
}

}  // namespace

void register_materials(pybind11::module& m) {
  m.def("constitutive_update", &constitutive_update_op,
        "The material update per particle: (F_trial (N,3,3) f32, state (N,S) or (N,) f32, material_table (M,8) f32, "
        "material_id (N,) i32) -> (F_E, state_new (shaped as state), tau, dissipated (N,))",
        pybind11::arg("F_trial"), pybind11::arg("state"), pybind11::arg("material_table"),
        pybind11::arg("material_id"));
  m.def("elastic_energy", &elastic_energy_op,
        "Elastic energy density per unit rest volume: (F_E, state (N,S) or (N,), material_table, material_id) -> psi (N,)",
        pybind11::arg("F_E"), pybind11::arg("state"), pybind11::arg("material_table"), pybind11::arg("material_id"));
  m.def("material_models", &material_models,
        "The material models of the kernels: [{code, name, parameters, state}] in code order");
  m.attr("max_state_fields") = static_cast<int>(kMaxStateFields);
  m.def("advance_split_directions", &advance_split_directions_op,
        "Split directions carried with the material, in place: (state (N,S) f32, trigger_old (N,) f32, C (N,3,3), "
        "F_E (N,3,3), mine (N,) bool, first, trigger, start, dt, orientation [3])",
        pybind11::arg("state"), pybind11::arg("trigger_old"), pybind11::arg("C"), pybind11::arg("F_E"),
        pybind11::arg("mine"), pybind11::arg("first"), pybind11::arg("trigger"), pybind11::arg("start"),
        pybind11::arg("dt"), pybind11::arg("orientation"));
  m.def("svd3_batch", &svd3_batch_op,
        "F = U diag(sigma) V^T with det U = det V = +1: F (N,3,3) f32 -> (U, sigma (N,3), V)",
        pybind11::arg("F"));
}

}  // namespace fgs
