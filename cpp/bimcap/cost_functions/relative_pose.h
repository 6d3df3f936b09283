// Odometry: consecutive frames keep the relative motion of the initial trajectory, loosely.
#ifndef BIMCAP_COST_FUNCTIONS_RELATIVE_POSE_H_
#define BIMCAP_COST_FUNCTIONS_RELATIVE_POSE_H_

#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "bimcap/pose.h"

namespace bimcap {

// A frame that neither the BIM terms nor G can place (it sees a bare wall from half a metre,
// its matches are too few) should move with its neighbours, not stay where the drift put it.
// The initial trajectory's relative motion between two frames a and b, which SLAM gets far more
// right than the absolute poses, is the measurement (Ceres' pose_graph_3d error term):
//
//   t_ab0 = R_a0ᵀ (t_b0 − t_a0),   q_ab0 = q_a0⁻¹ ⊗ q_b0                      (from the input)
//   t_ab  = R_aᵀ (t_b − t_a),      q_ab  = q_a⁻¹ ⊗ q_b                        (current)
//   δq = q_ab0⁻¹ ⊗ q_ab, sign chosen so that δq.w >= 0
//   r  = [ (t_ab − t_ab0) / sigma_t ;  2 · vec(δq) / sigma_r ]                 (6 residuals, in
//   sigmas)
//
// sigma_t in metres (in frame a), sigma_r in radians; both wide (the drift's per-frame noise),
// so that wherever the data see a frame they win.
// Parameter blocks:
//   world_from_cam_a [7]: tx ty tz qx qy qz qw of the earlier frame
//   world_from_cam_b [7]: the same for the later frame
struct RelativePoseCostFunctor {
  RelativePoseCostFunctor(const double* world_from_cam_a0, const double* world_from_cam_b0,
                          double sigma_t, double sigma_r)
      : inv_sigma_t(1.0 / sigma_t), inv_sigma_r(1.0 / sigma_r) {
    const Eigen::Quaterniond q_a0 = Eigen::Quaterniond(world_from_cam_a0[6], world_from_cam_a0[3],
                                                       world_from_cam_a0[4], world_from_cam_a0[5])
                                        .normalized();
    const Eigen::Quaterniond q_b0 = Eigen::Quaterniond(world_from_cam_b0[6], world_from_cam_b0[3],
                                                       world_from_cam_b0[4], world_from_cam_b0[5])
                                        .normalized();
    const Eigen::Vector3d t_a0(world_from_cam_a0[0], world_from_cam_a0[1], world_from_cam_a0[2]);
    const Eigen::Vector3d t_b0(world_from_cam_b0[0], world_from_cam_b0[1], world_from_cam_b0[2]);
    t_ab0 = q_a0.conjugate() * (t_b0 - t_a0);
    q_ab0_inverse = (q_a0.conjugate() * q_b0).conjugate();
  }

  static ceres::CostFunction* Create(const double* world_from_cam_a0,
                                     const double* world_from_cam_b0, double sigma_t,
                                     double sigma_r) {
    return new ceres::AutoDiffCostFunction<RelativePoseCostFunctor, 6, kPoseSize, kPoseSize>(
        new RelativePoseCostFunctor(world_from_cam_a0, world_from_cam_b0, sigma_t, sigma_r));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam_a, const T* const world_from_cam_b,
                  T* residuals) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_a(world_from_cam_a);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_b(world_from_cam_b);
    const Eigen::Map<const Eigen::Quaternion<T>> q_a(world_from_cam_a + 3);
    const Eigen::Map<const Eigen::Quaternion<T>> q_b(world_from_cam_b + 3);
    const Eigen::Quaternion<T> q_a_inverse = q_a.conjugate();
    const Eigen::Matrix<T, 3, 1> t_ab = q_a_inverse * (t_b - t_a);
    const Eigen::Quaternion<T> delta = q_ab0_inverse.cast<T>() * (q_a_inverse * q_b);
    const T sign = delta.w() < T(0) ? T(-1) : T(1);
    for (int k = 0; k < 3; ++k) {
      residuals[k] = (t_ab[k] - T(t_ab0[k])) * T(inv_sigma_t);
      residuals[3 + k] = T(2) * sign * delta.vec()[k] * T(inv_sigma_r);
    }
    return true;
  }

  Eigen::Vector3d t_ab0;
  Eigen::Quaterniond q_ab0_inverse;
  const double inv_sigma_t;
  const double inv_sigma_r;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_RELATIVE_POSE_H_
