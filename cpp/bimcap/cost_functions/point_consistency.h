// G, point consistency (FACaP's "point error").
#ifndef BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_
#define BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_

#include <ceres/autodiff_cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

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

// PointConsistencyCostFunctor with hand-written Jacobians (what the builder uses: the term is hot):
//   ∂r/∂pose_a = s [I, ∂(R_a p_a)/∂q_a],   ∂r/∂pose_b = −s [I, ∂(R_b p_b)/∂q_b]   (3 x 7 each).
class PointConsistencyCostFunction final
    : public ceres::SizedCostFunction<3, kPoseSize, kPoseSize> {
 public:
  PointConsistencyCostFunction(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector3d& p_b_in_cam,
                               double sqrt_weight)
      : p_a_in_cam_(p_a_in_cam), p_b_in_cam_(p_b_in_cam), sqrt_weight_(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_a_in_cam,
                                     const Eigen::Vector3d& p_b_in_cam, double sqrt_weight) {
    return new PointConsistencyCostFunction(p_a_in_cam, p_b_in_cam, sqrt_weight);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool jac_a = jacobians != nullptr && jacobians[0] != nullptr;
    const bool jac_b = jacobians != nullptr && jacobians[1] != nullptr;
    Eigen::Matrix<double, 3, 4> d_a, d_b;
    const Eigen::Vector3d p_a_in_world =
        CamToWorldWithJacobian(parameters[0], p_a_in_cam_, jac_a ? &d_a : nullptr);
    const Eigen::Vector3d p_b_in_world =
        CamToWorldWithJacobian(parameters[1], p_b_in_cam_, jac_b ? &d_b : nullptr);
    Eigen::Map<Eigen::Vector3d> r(residuals);
    r = sqrt_weight_ * (p_a_in_world - p_b_in_world);
    if (jac_a) {
      Eigen::Map<Eigen::Matrix<double, 3, kPoseSize, Eigen::RowMajor>> j(jacobians[0]);
      j.leftCols<3>() = sqrt_weight_ * Eigen::Matrix3d::Identity();
      j.rightCols<4>() = sqrt_weight_ * d_a;
    }
    if (jac_b) {
      Eigen::Map<Eigen::Matrix<double, 3, kPoseSize, Eigen::RowMajor>> j(jacobians[1]);
      j.leftCols<3>() = -sqrt_weight_ * Eigen::Matrix3d::Identity();
      j.rightCols<4>() = -sqrt_weight_ * d_b;
    }
    return true;
  }

 private:
  const Eigen::Vector3d p_a_in_cam_;
  const Eigen::Vector3d p_b_in_cam_;
  const double sqrt_weight_;
};

// The camera-frame point at z-depth `depth` through undistorted pixel (u, v) of a pinhole camera
// [fx, fy, cx, cy]: ((u − cx)/fx · depth, (v − cy)/fy · depth, depth).
inline Eigen::Vector3d BackprojectPixel(const double* intrinsics, double u, double v,
                                        double depth) {
  return Eigen::Vector3d((u - intrinsics[2]) / intrinsics[0] * depth,
                         (v - intrinsics[3]) / intrinsics[1] * depth, depth);
}

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POINT_CONSISTENCY_H_
