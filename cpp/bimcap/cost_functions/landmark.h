// G, landmark bundle adjustment: one 3-D point variable per feature track.
#ifndef BIMCAP_COST_FUNCTIONS_LANDMARK_H_
#define BIMCAP_COST_FUNCTIONS_LANDMARK_H_

#include <ceres/autodiff_cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/pose.h"

namespace bimcap {

// Classic bundle-adjustment reprojection error of a landmark X observed at undistorted pixel uv
// by a pinhole camera K = [fx, fy, cx, cy]:
//
//   p = Rᵀ (X − t),   r = s · ( [fx p.x / p.z + cx,  fy p.y / p.z + cy] − uv )     (2 residuals,
//   px)
//
// A landmark behind the camera gives a zero residual (as in COLMAP).
// Parameter blocks:
//   world_from_cam [7]:   tx ty tz qx qy qz qw
//   point_in_world [3]:   X, Y, Z in metres (Schur-eliminated by the solver)
struct LandmarkReprojectionCostFunctor {
  LandmarkReprojectionCostFunctor(const Eigen::Vector2d& uv, const Eigen::Vector4d& intrinsics,
                                  double sqrt_weight)
      : uv(uv), intrinsics(intrinsics), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector2d& uv, const Eigen::Vector4d& intrinsics,
                                     double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<LandmarkReprojectionCostFunctor, 2, kPoseSize, 3>(
        new LandmarkReprojectionCostFunctor(uv, intrinsics, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, const T* const point_in_world,
                  T* residuals) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> x(point_in_world);
    const Eigen::Matrix<T, 3, 1> p_in_cam = WorldToCam(world_from_cam, Eigen::Matrix<T, 3, 1>(x));
    T projected[2];
    if (!ProjectPinhole(intrinsics.data(), p_in_cam, projected)) {
      residuals[0] = T(0.0);
      residuals[1] = T(0.0);
      return true;
    }
    residuals[0] = T(sqrt_weight) * (projected[0] - T(uv.x()));
    residuals[1] = T(sqrt_weight) * (projected[1] - T(uv.y()));
    return true;
  }

  const Eigen::Vector2d uv;
  const Eigen::Vector4d intrinsics;
  const double sqrt_weight;
};

// LandmarkReprojectionCostFunctor with hand-written Jacobians (what the builder uses). With
// p = Rᵀ (X − t) and P = s ∂proj/∂p = s [[fx/z, 0, −fx x/z²], [0, fy/z, −fy y/z²]]:
//   ∂r/∂pose = [−P ∂p/∂X, P ∂p/∂q],   ∂r/∂X = P ∂p/∂X;   zero behind the camera.
class LandmarkReprojectionCostFunction final : public ceres::SizedCostFunction<2, kPoseSize, 3> {
 public:
  LandmarkReprojectionCostFunction(const Eigen::Vector2d& uv, const Eigen::Vector4d& intrinsics,
                                   double sqrt_weight)
      : uv_(uv), intrinsics_(intrinsics), sqrt_weight_(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector2d& uv, const Eigen::Vector4d& intrinsics,
                                     double sqrt_weight) {
    return new LandmarkReprojectionCostFunction(uv, intrinsics, sqrt_weight);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool jac_pose = jacobians != nullptr && jacobians[0] != nullptr;
    const bool jac_point = jacobians != nullptr && jacobians[1] != nullptr;
    const bool jac = jac_pose || jac_point;
    Eigen::Matrix3d d_world;
    Eigen::Matrix<double, 3, 4> d_q;
    const Eigen::Vector3d p =
        WorldToCamWithJacobian(parameters[0], Eigen::Map<const Eigen::Vector3d>(parameters[1]),
                               jac ? &d_world : nullptr, jac_pose ? &d_q : nullptr);
    Eigen::Map<Eigen::Matrix<double, 2, kPoseSize, Eigen::RowMajor>> j_pose(jac_pose ? jacobians[0]
                                                                                     : nullptr);
    Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> j_point(jac_point ? jacobians[1]
                                                                               : nullptr);
    double projected[2];
    if (!ProjectPinhole(intrinsics_.data(), p, projected)) {
      residuals[0] = 0.0;
      residuals[1] = 0.0;
      if (jac_pose) j_pose.setZero();
      if (jac_point) j_point.setZero();
      return true;
    }
    residuals[0] = sqrt_weight_ * (projected[0] - uv_.x());
    residuals[1] = sqrt_weight_ * (projected[1] - uv_.y());
    if (jac) {
      const double fx = intrinsics_[0], fy = intrinsics_[1], z = p.z();
      Eigen::Matrix<double, 2, 3> d_proj;
      d_proj << fx / z, 0.0, -fx * p.x() / (z * z), 0.0, fy / z, -fy * p.y() / (z * z);
      d_proj *= sqrt_weight_;
      const Eigen::Matrix<double, 2, 3> d_point = d_proj * d_world;
      if (jac_point) j_point = d_point;
      if (jac_pose) {
        j_pose.leftCols<3>() = -d_point;
        j_pose.rightCols<4>() = d_proj * d_q;
      }
    }
    return true;
  }

 private:
  const Eigen::Vector2d uv_;
  const Eigen::Vector4d intrinsics_;
  const double sqrt_weight_;
};

// Depth prior of a landmark from the observing frame's depth map:
//
//   r = s · ( (Rᵀ (X − t)).z − depth )                                            (1 residual, m)
//
// Parameter blocks: world_from_cam [7], point_in_world [3], as above.
struct LandmarkDepthCostFunctor {
  LandmarkDepthCostFunctor(double depth, double sqrt_weight)
      : depth(depth), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(double depth, double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<LandmarkDepthCostFunctor, 1, kPoseSize, 3>(
        new LandmarkDepthCostFunctor(depth, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, const T* const point_in_world,
                  T* residuals) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> x(point_in_world);
    const Eigen::Matrix<T, 3, 1> p_in_cam = WorldToCam(world_from_cam, Eigen::Matrix<T, 3, 1>(x));
    residuals[0] = T(sqrt_weight) * (p_in_cam.z() - T(depth));
    return true;
  }

  const double depth;
  const double sqrt_weight;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_LANDMARK_H_
