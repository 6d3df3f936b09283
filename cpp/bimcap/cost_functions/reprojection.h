// G, reprojection between two frames.
#ifndef BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
#define BIMCAP_COST_FUNCTIONS_REPROJECTION_H_

#include <Eigen/Core>
#include <ceres/autodiff_cost_function.h>

#include "bimcap/pose.h"

namespace bimcap {

// Pinhole projection of a camera-frame point into undistorted pixels. Returns false (and leaves
// `uv` untouched) for points at or behind the camera centre.
template <typename T>
bool ProjectPinhole(const double* intrinsics, const Eigen::Matrix<T, 3, 1>& p_in_cam, T* uv) {
  if (p_in_cam.z() < T(1e-9)) return false;
  uv[0] = T(intrinsics[0]) * p_in_cam.x() / p_in_cam.z() + T(intrinsics[2]);
  uv[1] = T(intrinsics[1]) * p_in_cam.y() / p_in_cam.z() + T(intrinsics[3]);
  return true;
}

// The keypoint of frame a, back-projected with its depth, mapped into frame b and projected with
// b's pinhole intrinsics K_b = [fx, fy, cx, cy], minus the matched keypoint observed in b:
//
//   p_b = R_bᵀ (R_a p_a + t_a − t_b)
//   r   = s · ( [fx p_b.x / p_b.z + cx,  fy p_b.y / p_b.z + cy] − uv_b )          (2 residuals, px)
//
// Like COLMAP's cost functions, a point that falls behind camera b gives a zero residual (the
// observation then drops out of the solve instead of aborting it).
// Parameter blocks:
//   world_from_cam_a [7]: tx ty tz qx qy qz qw of the frame the depth belongs to
//   world_from_cam_b [7]: the same for the frame the keypoint is re-observed in
struct ReprojectionCostFunctor {
  ReprojectionCostFunctor(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector2d& uv_b,
                          const Eigen::Vector4d& intrinsics_b, double sqrt_weight)
      : p_a_in_cam(p_a_in_cam), uv_b(uv_b), intrinsics_b(intrinsics_b), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_a_in_cam,
                                     const Eigen::Vector2d& uv_b,
                                     const Eigen::Vector4d& intrinsics_b, double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<ReprojectionCostFunctor, 2, kPoseSize, kPoseSize>(
        new ReprojectionCostFunctor(p_a_in_cam, uv_b, intrinsics_b, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam_a, const T* const world_from_cam_b,
                  T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_in_world =
        CamToWorld(world_from_cam_a, p_a_in_cam.cast<T>().eval());
    const Eigen::Matrix<T, 3, 1> p_b_in_cam = WorldToCam(world_from_cam_b, p_in_world);
    T uv[2];
    if (!ProjectPinhole(intrinsics_b.data(), p_b_in_cam, uv)) {
      residuals[0] = T(0.0);
      residuals[1] = T(0.0);
      return true;
    }
    residuals[0] = T(sqrt_weight) * (uv[0] - T(uv_b.x()));
    residuals[1] = T(sqrt_weight) * (uv[1] - T(uv_b.y()));
    return true;
  }

  const Eigen::Vector3d p_a_in_cam;
  const Eigen::Vector2d uv_b;
  const Eigen::Vector4d intrinsics_b;
  const double sqrt_weight;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
