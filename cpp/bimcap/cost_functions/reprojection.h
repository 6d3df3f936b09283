// G, reprojection between two frames, with the source keypoint's depth uncertainty.
#ifndef BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
#define BIMCAP_COST_FUNCTIONS_REPROJECTION_H_

#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>

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

// The keypoint of frame a, back-projected with its depth z_a, mapped into frame b and projected
// with b's pinhole intrinsics K_b = [fx, fy, cx, cy], minus the matched keypoint observed in b:
//
//   p_b = R_bᵀ (R_a p_a + t_a − t_b),     p_a = z_a · ray_a  (ray_a.z = 1)
//   e   = [fx p_b.x / p_b.z + cx,  fy p_b.y / p_b.z + cy] − uv_b                     (px)
//
// e has two sources of noise: the keypoints (σ_px per axis) and the depth z_a (σ_z metres),
// which moves the point along ray a and so e along j = ∂e/∂z_a (the epipolar line's direction
// in b, scaled by the parallax). Its covariance is Σ = σ_px² I + σ_z² j jᵀ, and the residual is
// the error whitened by it, in units of σ_px:
//
//   r = s · σ_px Σ^{-1/2} e = s · ( e − c j (j·e) ),
//   c = σ_z² / (q (q + σ_px)),   q = √(σ_px² + σ_z² |j|²)                             (2 residuals)
//
// i.e. the component across the epipolar line keeps its weight s, the one along it is scaled by
// σ_px / q. s is the term's square-root weight (1/σ_px in robust weighting, √(λ/N) in the
// peers' weighting, where σ_z = 0 keeps their objective exactly). The closed form is smooth at
// j = 0 (no parallax). Without it a depth error of a few centimetres on a close wall moves e by
// tens of pixels along the epipolar line and pulls the two frames' relative rotation; with it a
// depth counts only as much as it is known. j is evaluated at the current poses (inside the
// autodiff), so the weighting follows the solve.
// Like COLMAP's cost functions, a point that falls behind camera b gives a zero residual (the
// observation then drops out of the solve instead of aborting it).
// Parameter blocks:
//   world_from_cam_a [7]: tx ty tz qx qy qz qw of the frame the depth belongs to
//   world_from_cam_b [7]: the same for the frame the keypoint is re-observed in
struct ReprojectionCostFunctor {
  // `p_a_in_cam` = z_a · ray_a; `sqrt_weight` = s; `pixel_sigma` = σ_px (> 0);
  // `depth_sigma` = σ_z (metres, ≥ 0; 0 = the plain reprojection error s · e).
  ReprojectionCostFunctor(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector2d& uv_b,
                          const Eigen::Vector4d& intrinsics_b, double sqrt_weight,
                          double pixel_sigma = 1.0, double depth_sigma = 0.0)
      : p_a_in_cam(p_a_in_cam),
        uv_b(uv_b),
        intrinsics_b(intrinsics_b),
        sqrt_weight(sqrt_weight),
        pixel_sigma(pixel_sigma),
        depth_sigma(depth_sigma) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector2d& uv_b,
                                     const Eigen::Vector4d& intrinsics_b, double sqrt_weight,
                                     double pixel_sigma = 1.0, double depth_sigma = 0.0) {
    return new ceres::AutoDiffCostFunction<ReprojectionCostFunctor, 2, kPoseSize, kPoseSize>(
        new ReprojectionCostFunctor(p_a_in_cam, uv_b, intrinsics_b, sqrt_weight, pixel_sigma,
                                    depth_sigma));
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
    const T e0 = uv[0] - T(uv_b.x());
    const T e1 = uv[1] - T(uv_b.y());
    const T s = T(sqrt_weight);
    if (depth_sigma <= 0.0 || p_a_in_cam.z() <= 0.0) {
      residuals[0] = s * e0;
      residuals[1] = s * e1;
      return true;
    }
    // ∂p_b/∂z_a = R_bᵀ R_a ray_a: the rotation part of the same map, applied to the ray.
    const Eigen::Map<const Eigen::Quaternion<T>> q_a(world_from_cam_a + 3);
    const Eigen::Map<const Eigen::Quaternion<T>> q_b(world_from_cam_b + 3);
    const Eigen::Matrix<T, 3, 1> ray_a = (p_a_in_cam / p_a_in_cam.z()).cast<T>();
    const Eigen::Matrix<T, 3, 1> dp_b = q_b.conjugate() * (q_a * ray_a);
    const T iz = T(1.0) / p_b_in_cam.z();
    const T j0 = T(intrinsics_b[0]) * iz * (dp_b.x() - p_b_in_cam.x() * iz * dp_b.z());
    const T j1 = T(intrinsics_b[1]) * iz * (dp_b.y() - p_b_in_cam.y() * iz * dp_b.z());
    const T sp = T(pixel_sigma), sz = T(depth_sigma);
    const T q = sqrt(sp * sp + sz * sz * (j0 * j0 + j1 * j1));
    const T c = sz * sz / (q * (q + sp));
    const T je = j0 * e0 + j1 * e1;
    residuals[0] = s * (e0 - c * j0 * je);
    residuals[1] = s * (e1 - c * j1 * je);
    return true;
  }

  const Eigen::Vector3d p_a_in_cam;
  const Eigen::Vector2d uv_b;
  const Eigen::Vector4d intrinsics_b;
  const double sqrt_weight;
  const double pixel_sigma;
  const double depth_sigma;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
