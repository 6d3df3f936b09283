// Poses as 7 doubles and the manifolds they live on.
//
// A pose is `world_from_cam` stored in TUM order
//
//   [tx, ty, tz, qx, qy, qz, qw]   (translation, then a unit quaternion x, y, z, w)
//
// so that p_in_world = R(q) * p_in_cam + t. The (N, 7) pose array that Python passes in is used
// as the parameter blocks directly: each row is one 7-double block. The quaternion part is in
// Eigen's storage order (x, y, z, w), so it lives on ceres::EigenQuaternionManifold (NOT
// ceres::QuaternionManifold, which expects w, x, y, z). The block's tangent space is
// [δt (3), δθ (3)]: translation first, then the rotation increment of EigenQuaternionManifold
// (q ⊕ δθ = Exp(δθ) * q, a left / world-frame perturbation).
#ifndef BIMCAP_POSE_H_
#define BIMCAP_POSE_H_

#include <memory>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/manifold.h>

namespace bimcap {

inline constexpr int kPoseSize = 7;
inline constexpr int kPoseTangentSize = 6;

// Which part of each free pose the solver may change.
enum class RefineMode { kFull = 0, kRotation = 1, kTranslation = 2 };

// p_in_world = R * p_in_cam + t for a 7-double `world_from_cam` block. The quaternion is assumed
// to be of unit norm (the manifold keeps it so); no normalisation happens here.
template <typename T>
Eigen::Matrix<T, 3, 1> CamToWorld(const T* world_from_cam, const Eigen::Matrix<T, 3, 1>& p_in_cam) {
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(world_from_cam);
  const Eigen::Map<const Eigen::Quaternion<T>> q(world_from_cam + 3);
  return q * p_in_cam + t;
}

// p_in_cam = Rᵀ (p_in_world − t) for a 7-double `world_from_cam` block.
template <typename T>
Eigen::Matrix<T, 3, 1> WorldToCam(const T* world_from_cam,
                                  const Eigen::Matrix<T, 3, 1>& p_in_world) {
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(world_from_cam);
  const Eigen::Map<const Eigen::Quaternion<T>> q(world_from_cam + 3);
  return q.conjugate() * (p_in_world - t);
}

// The manifold of a 7-double pose block:
//   kFull:        ProductManifold<EuclideanManifold<3>, EigenQuaternionManifold>   (tangent 6)
//   kRotation:    translation held by a SubsetManifold, rotation free             (tangent 3)
//   kTranslation: rotation held by a SubsetManifold, translation free             (tangent 3)
std::unique_ptr<ceres::Manifold> CreatePoseManifold(RefineMode mode);

// A plane [nx, ny, nz, d] (signed distance n·p + d) with a unit normal on the sphere and a free
// offset: ProductManifold<SphereManifold<3>, EuclideanManifold<1>> (tangent 3).
std::unique_ptr<ceres::Manifold> CreatePlaneManifold();

}  // namespace bimcap

#endif  // BIMCAP_POSE_H_
