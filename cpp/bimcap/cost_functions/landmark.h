// G, landmark bundle adjustment: one 3-D point variable per feature track.
#ifndef BIMCAP_COST_FUNCTIONS_LANDMARK_H_
#define BIMCAP_COST_FUNCTIONS_LANDMARK_H_

#include <Eigen/Core>
#include <ceres/autodiff_cost_function.h>

#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/pose.h"

namespace bimcap {

// Classic bundle-adjustment reprojection error of a landmark X observed at undistorted pixel uv
// by a pinhole camera K = [fx, fy, cx, cy]:
//
//   p = Rᵀ (X − t),   r = s · ( [fx p.x / p.z + cx,  fy p.y / p.z + cy] − uv )     (2 residuals, px)
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
