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

// The first three columns of `out` = a [v]× + b [c]× + e [u]× [v]×, element by element
// ([u]× [v]× = v uᵀ − (u · v) I): the quaternion Jacobians of CamToWorldWithJacobian and
// WorldToCamWithJacobian without 3 × 3 products.
inline void SkewJacobian(double a, const Eigen::Vector3d& v, double b, const Eigen::Vector3d& c,
                         double e, const Eigen::Vector3d& u, Eigen::Matrix<double, 3, 4>* out) {
  const Eigen::Vector3d s = a * v + b * c;  // a [v]× + b [c]× = [s]×
  const Eigen::Vector3d ev = e * v;
  const double diag = -e * u.dot(v);
  Eigen::Matrix<double, 3, 4>& m = *out;
  m(0, 0) = ev.x() * u.x() + diag;
  m(0, 1) = -s.z() + ev.x() * u.y();
  m(0, 2) = s.y() + ev.x() * u.z();
  m(1, 0) = s.z() + ev.y() * u.x();
  m(1, 1) = ev.y() * u.y() + diag;
  m(1, 2) = -s.x() + ev.y() * u.z();
  m(2, 0) = -s.y() + ev.z() * u.x();
  m(2, 1) = s.x() + ev.z() * u.y();
  m(2, 2) = ev.z() * u.z() + diag;
}

// p_in_world = R * p_in_cam + t for a 7-double `world_from_cam` block, with the derivative of the
// rotated point R * p_in_cam with respect to the (ambient) quaternion [qx, qy, qz, qw] (3 x 4,
// row-major). The formula is Eigen's Quaternion * Vector3,
//   f = v + w (2 u × v) + u × (2 u × v),   q = [u, w],
// differentiated as written (not only on the unit sphere), so that the values and the ambient
// Jacobian equal those autodiff gives for CamToWorld (to rounding):
//   ∂f/∂w = 2 u × v,   ∂f/∂u = −2w [v]× − 2 [u × v]× − 2 [u]× [v]×,
// written out element by element with [u]× [v]× = v uᵀ − (u · v) I (no 3 × 3 products).
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
    SkewJacobian(-2.0 * w, v, -1.0, uv2, -2.0, u, d_rotated_d_q);
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
  if (d_p_d_world != nullptr) {
    // I + 2w [u]× + 2 [u]× [u]×, with [u]× [u]× = u uᵀ − (u · u) I.
    *d_p_d_world = 2.0 * u * u.transpose();
    d_p_d_world->diagonal().array() += 1.0 - 2.0 * u.squaredNorm();
    const Eigen::Vector3d wu = 2.0 * w * u;
    (*d_p_d_world)(0, 1) -= wu.z();
    (*d_p_d_world)(0, 2) += wu.y();
    (*d_p_d_world)(1, 0) += wu.z();
    (*d_p_d_world)(1, 2) -= wu.x();
    (*d_p_d_world)(2, 0) -= wu.y();
    (*d_p_d_world)(2, 1) += wu.x();
  }
  if (d_p_d_q != nullptr) {
    // ∂/∂(−u) as in CamToWorldWithJacobian, times −1 for the conjugate:
    // 2w [d]× + [2 u × d]× + 2 [u]× [d]×.
    SkewJacobian(2.0 * w, d, 1.0, ud2, 2.0, u, d_p_d_q);
    d_p_d_q->col(3) = ud2;
  }
  return d + w * ud2 + u.cross(ud2);
}

// A world_from_cam pose as a rotation matrix and a translation (R and t of a 7-double block, its
// quaternion taken as unit), for the observations of a batch that share it.
struct PoseMatrix {
  Eigen::Matrix3d rotation;     // R: p_in_world = R p_in_cam + t
  Eigen::Vector3d translation;  // t
  static PoseMatrix FromBlock(const double* world_from_cam) {
    PoseMatrix m;
    m.rotation = Eigen::Map<const Eigen::Quaterniond>(world_from_cam + 3).toRotationMatrix();
    m.translation = Eigen::Map<const Eigen::Vector3d>(world_from_cam);
    return m;
  }
};

// Frame a's camera seen from frame b's, b⁻¹ a: p_in_cam_b = rotation · p_in_cam_a + translation.
struct RelativePose {
  Eigen::Matrix3d rotation;     // R_bᵀ R_a
  Eigen::Vector3d translation;  // R_bᵀ (t_a − t_b)
  static RelativePose Between(const PoseMatrix& a, const PoseMatrix& b) {
    return {b.rotation.transpose() * a.rotation,
            b.rotation.transpose() * (a.translation - b.translation)};
  }
};

// The manifold of a 7-double pose block:
//   kFull:        ProductManifold<EuclideanManifold<3>, EigenQuaternionManifold>   (tangent 6)
//   kRotation:    translation held by a SubsetManifold, rotation free             (tangent 3)
//   kTranslation: rotation held by a SubsetManifold, translation free             (tangent 3)
std::unique_ptr<ceres::Manifold> CreatePoseManifold(RefineMode mode);
// Whether `manifold` is CreatePoseManifold(RefineMode::kFull)'s. Its Plus is t + δt and
// [δθ sin‖δθ‖ / ‖δθ‖, cos‖δθ‖] ⊗ q, so to first order R ⊕ δθ = (I + 2 [δθ]×) R: the tangent
// Jacobians of a rotated point are ∂(R p)/∂δt = 0, ∂(R p)/∂δθ = −2 [R p]×, and of a point
// brought into the camera, p_in_cam = Rᵀ (p_in_world − t): −Rᵀ and 2 Rᵀ [p_in_world − t]×.
bool IsFullPoseManifold(const ceres::Manifold* manifold);

// On that manifold, a step δ_a = [δt_a, δθ_a] of pose a changes b⁻¹ a as the step δ_b = E_ab δ_a
// of pose b does (to first order: R_bᵀ (I + 2 [δθ_a]×) R_a = (R_b (I − 2 [δθ_a]×))ᵀ R_a, and
// the translation follows), with d = t_a − t_b:
//
//   E_ab = [ −I   −2 [d]× ]
//          [  0     −I    ]
//
// so a residual of b⁻¹ a alone has ∂r/∂δ_a = ∂r/∂δ_b E_ab. Writes `rows_b` · E_ab (rows × 6,
// row-major, `stride` apart) into `rows_a`.
inline void RelativeTangentMap(const Eigen::Vector3d& d, const double* rows_b, int rows, int stride,
                               double* rows_a) {
  for (int i = 0; i < rows; ++i) {
    const double* x = rows_b + i * stride;
    double* y = rows_a + i * stride;
    // x_t [d]× = (x_t × d) as a row.
    const Eigen::Vector3d x_t(x[0], x[1], x[2]);
    const Eigen::Vector3d c = x_t.cross(d);
    for (int k = 0; k < 3; ++k) {
      y[k] = -x[k];
      y[3 + k] = -2.0 * c[k] - x[3 + k];
    }
  }
}

// A plane [nx, ny, nz, d] (signed distance n·p + d) with a unit normal on the sphere and a free
// offset: ProductManifold<SphereManifold<3>, EuclideanManifold<1>> (tangent 3).
std::unique_ptr<ceres::Manifold> CreatePlaneManifold();

}  // namespace bimcap

#endif  // BIMCAP_POSE_H_
