// Pose prior: a weak anchor of a free pose at its initial value.
#ifndef BIMCAP_COST_FUNCTIONS_POSE_PRIOR_H_
#define BIMCAP_COST_FUNCTIONS_POSE_PRIOR_H_

#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "bimcap/pose.h"

namespace bimcap {

// The enabled terms need not observe every degree of freedom of a pose (F alone sees z, roll and
// pitch only); without an anchor Levenberg–Marquardt leaks steps into the unobserved directions.
// This residual holds a pose near its initial value world_from_cam0 = [t0, q0]:
//
//   δq = q0⁻¹ ⊗ q, sign chosen so that δq.w >= 0 (q and −q give the same residual)
//   r  = [ (t − t0) / sigma_t ;  2 · vec(δq) / sigma_r ]                     (6 residuals, in
//   sigmas)
//
// 2 · vec(δq) = 2 sin(θ/2) · axis ≈ θ · axis (rad), the rotation from q0 to q in q0's frame.
// sigma_t in metres, sigma_r in radians. q0 is normalised here; q is unit (the manifold keeps it).
//
// Parameter blocks:
//   world_from_cam [7]: tx ty tz qx qy qz qw
struct PosePriorCostFunctor {
  PosePriorCostFunctor(const double* world_from_cam0, double sigma_t, double sigma_r)
      : t0(world_from_cam0[0], world_from_cam0[1], world_from_cam0[2]),
        q0_inverse(Eigen::Quaterniond(world_from_cam0[6], world_from_cam0[3], world_from_cam0[4],
                                      world_from_cam0[5])
                       .normalized()
                       .conjugate()),
        inv_sigma_t(1.0 / sigma_t),
        inv_sigma_r(1.0 / sigma_r) {}

  static ceres::CostFunction* Create(const double* world_from_cam0, double sigma_t,
                                     double sigma_r) {
    return new ceres::AutoDiffCostFunction<PosePriorCostFunctor, 6, kPoseSize>(
        new PosePriorCostFunctor(world_from_cam0, sigma_t, sigma_r));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, T* residuals) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(world_from_cam);
    const Eigen::Map<const Eigen::Quaternion<T>> q(world_from_cam + 3);
    const Eigen::Quaternion<T> delta = q0_inverse.cast<T>() * q;
    const T sign = delta.w() < T(0) ? T(-1) : T(1);
    for (int k = 0; k < 3; ++k) {
      residuals[k] = (t[k] - T(t0[k])) * T(inv_sigma_t);
      residuals[3 + k] = T(2) * sign * delta.vec()[k] * T(inv_sigma_r);
    }
    return true;
  }

  const Eigen::Vector3d t0;
  const Eigen::Quaterniond q0_inverse;
  const double inv_sigma_t;
  const double inv_sigma_r;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POSE_PRIOR_H_
