// Single-residual evaluation of the cost functions, for tests against independent oracles
// (pycolmap.cost_functions) and for debugging.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <memory>

#include "bimcap/cost_functions/landmark.h"
#include "bimcap/cost_functions/reprojection.h"
#include "python/arrays.h"

namespace bimcap::python {
namespace {

using Vec = py::array_t<double, py::array::c_style | py::array::forcecast>;

const double* Checked(const Vec& a, py::ssize_t size, const char* name) {
  if (a.ndim() != 1 || a.shape(0) != size) {
    throw py::value_error(std::string(name) + ": expected shape (" + std::to_string(size) + ",)");
  }
  return a.data();
}

// Evaluates `cost` at `blocks`; returns (residuals, [jacobian per block (R, block size)]).
py::tuple Evaluate(const ceres::CostFunction& cost, const std::vector<const double*>& blocks) {
  const int num_residuals = cost.num_residuals();
  py::array_t<double> residuals(num_residuals);
  std::vector<py::array_t<double>> jacobians;
  std::vector<double*> jacobian_ptrs;
  for (size_t i = 0; i < blocks.size(); ++i) {
    jacobians.emplace_back(
        std::vector<py::ssize_t>{num_residuals, cost.parameter_block_sizes()[i]});
    jacobian_ptrs.push_back(jacobians.back().mutable_data());
  }
  if (!cost.Evaluate(blocks.data(), residuals.mutable_data(), jacobian_ptrs.data())) {
    throw py::value_error("cost function evaluation failed");
  }
  py::list jac;
  for (auto& j : jacobians) jac.append(j);
  return py::make_tuple(residuals, py::tuple(jac));
}

}  // namespace

void BindCostFunctions(py::module_& m) {
  m.def(
      "evaluate_reprojection",
      [](const Vec& world_from_cam_a, const Vec& world_from_cam_b, const Vec& p_a_in_cam,
         const Vec& uv_b, const Vec& intrinsics_b) {
        const double* pa = Checked(p_a_in_cam, 3, "p_a_in_cam");
        const double* uv = Checked(uv_b, 2, "uv_b");
        const double* k = Checked(intrinsics_b, 4, "intrinsics_b");
        std::unique_ptr<ceres::CostFunction> cost(ReprojectionCostFunctor::Create(
            Eigen::Vector3d(pa[0], pa[1], pa[2]), Eigen::Vector2d(uv[0], uv[1]),
            Eigen::Vector4d(k[0], k[1], k[2], k[3]), 1.0));
        return Evaluate(*cost, {Checked(world_from_cam_a, 7, "world_from_cam_a"),
                                Checked(world_from_cam_b, 7, "world_from_cam_b")});
      },
      py::arg("world_from_cam_a"), py::arg("world_from_cam_b"), py::arg("p_a_in_cam"),
      py::arg("uv_b"), py::arg("intrinsics_b"),
      "The two-frame reprojection residual (2,) (weight 1) and its Jacobians ((2, 7), (2, 7)) "
      "with respect to the two 7-double TUM-order pose blocks (ambient, not tangent).");
  m.def(
      "evaluate_landmark",
      [](const Vec& world_from_cam, const Vec& point_in_world, const Vec& uv,
         const Vec& intrinsics) {
        const double* obs = Checked(uv, 2, "uv");
        const double* k = Checked(intrinsics, 4, "intrinsics");
        std::unique_ptr<ceres::CostFunction> cost(LandmarkReprojectionCostFunctor::Create(
            Eigen::Vector2d(obs[0], obs[1]), Eigen::Vector4d(k[0], k[1], k[2], k[3]), 1.0));
        return Evaluate(*cost, {Checked(world_from_cam, 7, "world_from_cam"),
                                Checked(point_in_world, 3, "point_in_world")});
      },
      py::arg("world_from_cam"), py::arg("point_in_world"), py::arg("uv"), py::arg("intrinsics"),
      "The landmark reprojection residual (2,) and its Jacobians ((2, 7) pose, (2, 3) point).");
}

}  // namespace bimcap::python
