// F / Ce, point-to-plane.
#ifndef BIMCAP_COST_FUNCTIONS_POINT_TO_PLANE_H_
#define BIMCAP_COST_FUNCTIONS_POINT_TO_PLANE_H_

#include <ceres/autodiff_cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

#include "bimcap/cost_functions/pose_tangent.h"
#include "bimcap/pose.h"

namespace bimcap {

// BIM mode: a floor (ceiling) point seen in the camera, mapped to the world, has a signed
// distance to its fixed BIM plane [n, d] (unit n, n·p + d = 0 on the plane):
//
//   r = s · ( n · (R p_in_cam + t) + d )                                          (1 residual, m)
//
// Parameter blocks:
//   world_from_cam [7]: tx ty tz qx qy qz qw
struct PointToPlaneCostFunctor {
  PointToPlaneCostFunctor(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& plane,
                          double sqrt_weight)
      : p_in_cam(p_in_cam), plane(plane), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& plane,
                                     double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<PointToPlaneCostFunctor, 1, kPoseSize>(
        new PointToPlaneCostFunctor(p_in_cam, plane, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_in_world = CamToWorld(world_from_cam, p_in_cam.cast<T>().eval());
    residuals[0] = T(sqrt_weight) * (plane.head<3>().cast<T>().dot(p_in_world) + T(plane[3]));
    return true;
  }

  const Eigen::Vector3d p_in_cam;
  const Eigen::Vector4d plane;
  const double sqrt_weight;
};

// PointToPlaneCostFunctor with hand-written Jacobians (what the builder uses: the term is hot).
// The ambient Jacobian is [s n, s nᵀ ∂(R p)/∂q], equal to the autodiff one to rounding; in the
// tangent space (EvaluateTangent) it is [s n, −2 s n × R p].
class PointToPlaneCostFunction final : public PoseTangentCostFunction {
 public:
  PointToPlaneCostFunction(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& plane,
                           double sqrt_weight)
      : p_in_cam_(p_in_cam), plane_(plane), sqrt_weight_(sqrt_weight) {
    set_num_residuals(1);
    *mutable_parameter_block_sizes() = {kPoseSize};
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& plane,
                                     double sqrt_weight) {
    return new PointToPlaneCostFunction(p_in_cam, plane, sqrt_weight);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool jac = jacobians != nullptr && jacobians[0] != nullptr;
    Eigen::Matrix<double, 3, 4> d_dq;
    const Eigen::Vector3d p_in_world =
        CamToWorldWithJacobian(parameters[0], p_in_cam_, jac ? &d_dq : nullptr);
    const Eigen::Vector3d n = plane_.head<3>();
    residuals[0] = sqrt_weight_ * (n.dot(p_in_world) + plane_[3]);
    if (jac) {
      Eigen::Map<Eigen::Matrix<double, 1, kPoseSize>> j(jacobians[0]);
      j.head<3>() = sqrt_weight_ * n.transpose();
      j.tail<4>() = sqrt_weight_ * (n.transpose() * d_dq);
    }
    return true;
  }

  bool EvaluateTangent(const PoseMatrix* poses, double* residuals,
                       double* jacobian) const override {
    const Eigen::Vector3d rotated = poses[0].rotation * p_in_cam_;  // R p
    const Eigen::Vector3d n = plane_.head<3>();
    residuals[0] = sqrt_weight_ * (n.dot(rotated + poses[0].translation) + plane_[3]);
    if (jacobian != nullptr) {
      Eigen::Map<Eigen::Matrix<double, 1, kPoseTangentSize>> j(jacobian);
      j.head<3>() = sqrt_weight_ * n.transpose();
      j.tail<3>() = -2.0 * sqrt_weight_ * n.cross(rotated).transpose();
    }
    return true;
  }

 private:
  const Eigen::Vector3d p_in_cam_;
  const Eigen::Vector4d plane_;
  const double sqrt_weight_;
};

// FACaP mode: the plane is a variable shared by all points of the term (flatness only; the
// scan's own floor fixes no absolute height):
//
//   r = s · ( n · (R p_in_cam + t) + d ),   [n, d] on SphereManifold<3> × EuclideanManifold<1>
//
// Parameter blocks:
//   world_from_cam [7]: tx ty tz qx qy qz qw
//   plane [4]:          nx ny nz d (unit normal kept by the manifold)
struct PointToVariablePlaneCostFunctor {
  PointToVariablePlaneCostFunctor(const Eigen::Vector3d& p_in_cam, double sqrt_weight)
      : p_in_cam(p_in_cam), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_in_cam, double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<PointToVariablePlaneCostFunctor, 1, kPoseSize, 4>(
        new PointToVariablePlaneCostFunctor(p_in_cam, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, const T* const plane, T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_in_world = CamToWorld(world_from_cam, p_in_cam.cast<T>().eval());
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> normal(plane);
    residuals[0] = T(sqrt_weight) * (normal.dot(p_in_world) + plane[3]);
    return true;
  }

  const Eigen::Vector3d p_in_cam;
  const double sqrt_weight;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POINT_TO_PLANE_H_
