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

#include <ceres/manifold.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>

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

// p_in_world = R * p_in_cam + t for a 7-double `world_from_cam` block, with the derivative of the
// rotated point R * p_in_cam with respect to the (ambient) quaternion [qx, qy, qz, qw] (3 x 4,
// row-major). The formula is Eigen's Quaternion * Vector3,
//   f = v + w (2 u × v) + u × (2 u × v),   q = [u, w],
// differentiated as written (not only on the unit sphere), so that the values and the ambient
// Jacobian equal those autodiff gives for CamToWorld (to rounding):
//   ∂f/∂w = 2 u × v,   ∂f/∂u = −2w [v]× − 2 [u × v]× − 2 [u]× [v]×.
inline Eigen::Vector3d CamToWorldWithJacobian(const double* world_from_cam,
                                              const Eigen::Vector3d& p_in_cam,
                                              Eigen::Matrix<double, 3, 4>* d_rotated_d_q) {
  const Eigen::Map<const Eigen::Vector3d> t(world_from_cam);
  const Eigen::Map<const Eigen::Vector3d> u(world_from_cam + 3);
  const double w = world_from_cam[6];
  const Eigen::Vector3d& v = p_in_cam;
  const Eigen::Vector3d uv = u.cross(v);
  const Eigen::Vector3d uv2 = 2.0 * uv;
  if (d_rotated_d_q != nullptr) {
    auto skew = [](const Eigen::Vector3d& a) {
      Eigen::Matrix3d m;
      m << 0.0, -a.z(), a.y(), a.z(), 0.0, -a.x(), -a.y(), a.x(), 0.0;
      return m;
    };
    const Eigen::Matrix3d v_x = skew(v);
    d_rotated_d_q->leftCols<3>() = -2.0 * w * v_x - skew(uv2) - 2.0 * skew(u) * v_x;
    d_rotated_d_q->col(3) = uv2;
  }
  return v + w * uv2 + u.cross(uv2) + t;
}

// p_in_cam = Rᵀ (p_in_world − t) for a 7-double `world_from_cam` block.
template <typename T>
Eigen::Matrix<T, 3, 1> WorldToCam(const T* world_from_cam,
                                  const Eigen::Matrix<T, 3, 1>& p_in_world) {
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(world_from_cam);
  const Eigen::Map<const Eigen::Quaternion<T>> q(world_from_cam + 3);
  return q.conjugate() * (p_in_world - t);
}

// p_in_cam = Rᵀ (p_in_world − t) with Eigen's formula for the conjugate quaternion [−u, w], and
// its derivatives as autodiff gives them for WorldToCam: d_p_d_world (3 x 3, the map the formula
// applies; Rᵀ for a unit quaternion; ∂/∂t is its negative) and d_p_d_q (3 x 4, [qx qy qz qw]).
inline Eigen::Vector3d WorldToCamWithJacobian(const double* world_from_cam,
                                              const Eigen::Vector3d& p_in_world,
                                              Eigen::Matrix3d* d_p_d_world,
                                              Eigen::Matrix<double, 3, 4>* d_p_d_q) {
  const Eigen::Map<const Eigen::Vector3d> t(world_from_cam);
  const Eigen::Vector3d u = -Eigen::Map<const Eigen::Vector3d>(world_from_cam + 3);  // conjugate
  const double w = world_from_cam[6];
  const Eigen::Vector3d d = p_in_world - t;
  const Eigen::Vector3d ud2 = 2.0 * u.cross(d);
  if (d_p_d_world != nullptr || d_p_d_q != nullptr) {
    auto skew = [](const Eigen::Vector3d& a) {
      Eigen::Matrix3d m;
      m << 0.0, -a.z(), a.y(), a.z(), 0.0, -a.x(), -a.y(), a.x(), 0.0;
      return m;
    };
    const Eigen::Matrix3d u_x = skew(u);
    if (d_p_d_world != nullptr) {
      *d_p_d_world = Eigen::Matrix3d::Identity() + 2.0 * w * u_x + 2.0 * u_x * u_x;
    }
    if (d_p_d_q != nullptr) {
      // ∂/∂(−u) as in CamToWorldWithJacobian, times −1 for the conjugate.
      const Eigen::Matrix3d d_x = skew(d);
      d_p_d_q->leftCols<3>() = 2.0 * w * d_x + skew(ud2) + 2.0 * u_x * d_x;
      d_p_d_q->col(3) = ud2;
    }
  }
  return d + w * ud2 + u.cross(ud2);
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
