// G, point consistency (FACaP's "point error").
#ifndef BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_
#define BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_

#include <Eigen/Core>
#include <ceres/autodiff_cost_function.h>

#include "bimcap/pose.h"

namespace bimcap {

// A keypoint matched between frames a and b, back-projected in each frame with its own depth,
// must land on the same world point:
//
//   r = s · ( (R_a p_a + t_a) − (R_b p_b + t_b) )                               (3 residuals, m·s)
//
// p_a, p_b: the keypoint in camera a / b (pixel back-projected at its z-depth, see
//           BackprojectPixel), s: the scalar square-root weight of the term.
// Parameter blocks:
//   world_from_cam_a [7]: tx ty tz qx qy qz qw of frame a
//   world_from_cam_b [7]: the same for frame b
struct PointConsistencyCostFunctor {
  PointConsistencyCostFunctor(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector3d& p_b_in_cam,
                              double sqrt_weight)
      : p_a_in_cam(p_a_in_cam), p_b_in_cam(p_b_in_cam), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_a_in_cam,
                                     const Eigen::Vector3d& p_b_in_cam, double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<PointConsistencyCostFunctor, 3, kPoseSize, kPoseSize>(
        new PointConsistencyCostFunctor(p_a_in_cam, p_b_in_cam, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam_a, const T* const world_from_cam_b,
                  T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_a_in_world =
        CamToWorld(world_from_cam_a, p_a_in_cam.cast<T>().eval());
    const Eigen::Matrix<T, 3, 1> p_b_in_world =
        CamToWorld(world_from_cam_b, p_b_in_cam.cast<T>().eval());
    Eigen::Map<Eigen::Matrix<T, 3, 1>> r(residuals);
    r = T(sqrt_weight) * (p_a_in_world - p_b_in_world);
    return true;
  }

  const Eigen::Vector3d p_a_in_cam;
  const Eigen::Vector3d p_b_in_cam;
  const double sqrt_weight;
};

// The camera-frame point at z-depth `depth` through undistorted pixel (u, v) of a pinhole camera
// [fx, fy, cx, cy]: ((u − cx)/fx · depth, (v − cy)/fy · depth, depth).
inline Eigen::Vector3d BackprojectPixel(const double* intrinsics, double u, double v, double depth) {
  return Eigen::Vector3d((u - intrinsics[2]) / intrinsics[0] * depth,
                         (v - intrinsics[3]) / intrinsics[1] * depth, depth);
}

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_
