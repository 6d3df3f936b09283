// W / Co, point-to-segment in the floor plane.
#ifndef BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_
#define BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_

#include <cmath>

#include <Eigen/Core>
#include <ceres/autodiff_cost_function.h>

#include "bimcap/pose.h"

namespace bimcap {

// Distance in the floor plane (xy) from point q to the segment a→b, written so that it stays
// differentiable: where q projects inside the segment it is the *signed* perpendicular distance
//   ((b − a) × (q − a)) / |b − a|      (positive on the left of a→b)
// whose square is the squared distance but whose derivative exists on the segment itself; past
// an end it is the Euclidean distance to that end point. Degenerate segments (a = b) use the
// distance to a.
template <typename T>
T PointToSegmentDistance2D(const T& qx, const T& qy, const Eigen::Vector4d& segment) {
  using std::sqrt;
  const double ax = segment[0], ay = segment[1];
  const double dx = segment[2] - ax, dy = segment[3] - ay;
  const double length2 = dx * dx + dy * dy;
  const T ex = qx - T(ax), ey = qy - T(ay);
  if (length2 > 1e-18) {
    const T along = (ex * dx + ey * dy) / length2;  // 0 at a, 1 at b
    if (along >= T(0.0) && along <= T(1.0)) {
      return (T(dx) * ey - T(dy) * ex) / std::sqrt(length2);
    }
    if (along > T(1.0)) {
      const T fx = qx - T(segment[2]), fy = qy - T(segment[3]);
      const T d2 = fx * fx + fy * fy;
      return d2 > T(0.0) ? sqrt(d2) : T(0.0);
    }
  }
  const T d2 = ex * ex + ey * ey;
  return d2 > T(0.0) ? sqrt(d2) : T(0.0);
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

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POINT_TO_SEGMENT_H_
