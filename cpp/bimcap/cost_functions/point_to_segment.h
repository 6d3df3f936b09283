// W / Co, point-to-segment in the floor plane.
#ifndef BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_
#define BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_

#include <ceres/autodiff_cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "bimcap/cost_functions/pose_tangent.h"
#include "bimcap/pose.h"

namespace bimcap {

// Distance in the floor plane (xy) from point q to the segment a→b, written so that it stays
// continuous and differentiable almost everywhere. Where q projects inside the segment it is the
// *signed* perpendicular distance
//   c = ((b − a) × (q − a)) / |b − a|      (positive on the left of a→b)
// whose square is the squared distance but whose derivative exists on the segment itself; past
// an end it is the Euclidean distance to that end point carrying the sign of c, so that the
// residual does not jump where the two pieces meet. Degenerate segments (a = b) use the distance
// to a.
template <typename T>
T PointToSegmentDistance2D(const T& qx, const T& qy, const Eigen::Vector4d& segment) {
  using std::sqrt;
  const double ax = segment[0], ay = segment[1];
  const double dx = segment[2] - ax, dy = segment[3] - ay;
  const double length2 = dx * dx + dy * dy;
  const T ex = qx - T(ax), ey = qy - T(ay);
  auto norm = [](const T& x, const T& y) {
    const T d2 = x * x + y * y;
    return d2 > T(0.0) ? T(sqrt(d2)) : T(0.0);
  };
  if (length2 <= 1e-18) return norm(ex, ey);
  const T cross = (T(dx) * ey - T(dy) * ex) / std::sqrt(length2);
  const T along = (ex * dx + ey * dy) / length2;  // 0 at a, 1 at b
  if (along >= T(0.0) && along <= T(1.0)) return cross;
  const T end = along > T(1.0) ? norm(qx - T(segment[2]), qy - T(segment[3])) : norm(ex, ey);
  return cross < T(0.0) ? T(-end) : end;
}

// PointToSegmentDistance2D with its gradient (∂/∂qx, ∂/∂qy), written piece by piece as autodiff
// differentiates it (a zero gradient where the end-point distance is exactly 0).
inline double PointToSegmentDistance2DWithGradient(double qx, double qy,
                                                   const Eigen::Vector4d& segment,
                                                   Eigen::Vector2d* gradient) {
  const double ax = segment[0], ay = segment[1];
  const double dx = segment[2] - ax, dy = segment[3] - ay;
  const double length2 = dx * dx + dy * dy;
  const double ex = qx - ax, ey = qy - ay;
  auto norm = [gradient](double x, double y) {
    const double d2 = x * x + y * y;
    if (!(d2 > 0.0)) {
      gradient->setZero();
      return 0.0;
    }
    const double d = std::sqrt(d2);
    *gradient = Eigen::Vector2d(x / d, y / d);
    return d;
  };
  if (length2 <= 1e-18) return norm(ex, ey);
  const double length = std::sqrt(length2);
  const double cross = (dx * ey - dy * ex) / length;
  const double along = (ex * dx + ey * dy) / length2;
  if (along >= 0.0 && along <= 1.0) {
    *gradient = Eigen::Vector2d(-dy / length, dx / length);
    return cross;
  }
  const double end = along > 1.0 ? norm(qx - segment[2], qy - segment[3]) : norm(ex, ey);
  if (cross < 0.0) {
    *gradient = -*gradient;
    return -end;
  }
  return end;
}

// A wall (column) point seen in the camera, mapped to the world and projected onto the floor
// plane, has a distance to its associated floor-plan segment [x1, y1, x2, y2] (metres, world xy):
//
//   q = (R p_in_cam + t).xy,   r = s · dist_2D(q, segment)                        (1 residual, m)
//
// The association (which segment) is fixed inside one Ceres run and recomputed between runs as
// the poses move (see association.h).
// Parameter blocks:
//   world_from_cam [7]: tx ty tz qx qy qz qw
struct PointToSegmentCostFunctor {
  PointToSegmentCostFunctor(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& segment,
                            double sqrt_weight)
      : p_in_cam(p_in_cam), segment(segment), sqrt_weight(sqrt_weight) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_in_cam,
                                     const Eigen::Vector4d& segment, double sqrt_weight) {
    return new ceres::AutoDiffCostFunction<PointToSegmentCostFunctor, 1, kPoseSize>(
        new PointToSegmentCostFunctor(p_in_cam, segment, sqrt_weight));
  }

  template <typename T>
  bool operator()(const T* const world_from_cam, T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_in_world = CamToWorld(world_from_cam, p_in_cam.cast<T>().eval());
    residuals[0] =
        T(sqrt_weight) * PointToSegmentDistance2D(p_in_world.x(), p_in_world.y(), segment);
    return true;
  }

  const Eigen::Vector3d p_in_cam;
  const Eigen::Vector4d segment;
  const double sqrt_weight;
};

// PointToSegmentCostFunctor with hand-written Jacobians (what the builder uses: the term is hot).
// With g = s ∂dist/∂q (a 3-vector, z = 0): ambient [g, gᵀ ∂(R p)/∂q], tangent (EvaluateTangent)
// [g, −2 g × R p].
class PointToSegmentCostFunction final : public PoseTangentCostFunction {
 public:
  PointToSegmentCostFunction(const Eigen::Vector3d& p_in_cam, const Eigen::Vector4d& segment,
                             double sqrt_weight)
      : p_in_cam_(p_in_cam), segment_(segment), sqrt_weight_(sqrt_weight) {
    set_num_residuals(1);
    *mutable_parameter_block_sizes() = {kPoseSize};
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_in_cam,
                                     const Eigen::Vector4d& segment, double sqrt_weight) {
    return new PointToSegmentCostFunction(p_in_cam, segment, sqrt_weight);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool jac = jacobians != nullptr && jacobians[0] != nullptr;
    Eigen::Matrix<double, 3, 4> d_dq;
    const Eigen::Vector3d p_in_world =
        CamToWorldWithJacobian(parameters[0], p_in_cam_, jac ? &d_dq : nullptr);
    Eigen::Vector2d g;
    residuals[0] = sqrt_weight_ * PointToSegmentDistance2DWithGradient(
                                      p_in_world.x(), p_in_world.y(), segment_, &g);
    if (jac) {
      Eigen::Map<Eigen::Matrix<double, 1, kPoseSize>> j(jacobians[0]);
      g *= sqrt_weight_;
      j << g.x(), g.y(), 0.0, g.transpose() * d_dq.topRows<2>();
    }
    return true;
  }

  bool EvaluateTangent(const PoseMatrix* poses, double* residuals,
                       double* jacobian) const override {
    const Eigen::Vector3d rotated = poses[0].rotation * p_in_cam_;  // R p
    const Eigen::Vector3d p_in_world = rotated + poses[0].translation;
    Eigen::Vector2d g;
    residuals[0] = sqrt_weight_ * PointToSegmentDistance2DWithGradient(
                                      p_in_world.x(), p_in_world.y(), segment_, &g);
    if (jacobian != nullptr) {
      const Eigen::Vector3d g3(sqrt_weight_ * g.x(), sqrt_weight_ * g.y(), 0.0);
      Eigen::Map<Eigen::Matrix<double, 1, kPoseTangentSize>> j(jacobian);
      j.head<3>() = g3.transpose();
      j.tail<3>() = -2.0 * g3.cross(rotated).transpose();
    }
    return true;
  }

 private:
  const Eigen::Vector3d p_in_cam_;
  const Eigen::Vector4d segment_;
  const double sqrt_weight_;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_
