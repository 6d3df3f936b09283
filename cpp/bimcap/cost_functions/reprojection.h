// G, reprojection between two frames, with the source keypoint's depth uncertainty.
#ifndef BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
#define BIMCAP_COST_FUNCTIONS_REPROJECTION_H_

#include <ceres/autodiff_cost_function.h>
#include <ceres/jet.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "bimcap/cost_functions/pose_tangent.h"
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
// The residual of ReprojectionCostFunctor (below) from the point in camera b, p_b, and the
// direction it moves in with the depth, dp_b = ∂p_b/∂z_a = R_bᵀ R_a ray_a. False (and r = 0)
// for a point at or behind camera b's centre.
template <typename T>
bool ReprojectionResidual(const Eigen::Matrix<T, 3, 1>& p_b_in_cam,
                          const Eigen::Matrix<T, 3, 1>& dp_b, const Eigen::Vector2d& uv_b,
                          const Eigen::Vector4d& intrinsics_b, double sqrt_weight,
                          double pixel_sigma, double depth_sigma, T* residuals) {
  using std::sqrt;
  T uv[2];
  if (!ProjectPinhole(intrinsics_b.data(), p_b_in_cam, uv)) {
    residuals[0] = T(0.0);
    residuals[1] = T(0.0);
    return false;
  }
  const T e0 = uv[0] - T(uv_b.x());
  const T e1 = uv[1] - T(uv_b.y());
  const T s = T(sqrt_weight);
  if (depth_sigma <= 0.0) {
    residuals[0] = s * e0;
    residuals[1] = s * e1;
    return true;
  }
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

// G_p = ∂r/∂p_b and G_d = ∂r/∂dp_b (2 × 3) of ReprojectionResidual, by hand (what a Jet through
// it gives, to rounding, at a fifth of the work). With ι = 1/p_b.z, e = [fx p_b.x ι + cx,
// fy p_b.y ι + cy] − uv_b and j = [fx ι (dp.x − p_b.x ι dp.z), fy ι (dp.y − p_b.y ι dp.z)]:
//
//   ∂e0/∂p_b = fx ι [1, 0, −p_b.x ι],   ∂e1/∂p_b = fy ι [0, 1, −p_b.y ι],   ∂e/∂dp = 0
//   ∂j0/∂p_b = fx ι² [−dp.z, 0, 2 p_b.x ι dp.z − dp.x],   ∂j0/∂dp = fx ι [1, 0, −p_b.x ι]
//   ∂j1/∂p_b = fy ι² [0, −dp.z, 2 p_b.y ι dp.z − dp.y],   ∂j1/∂dp = fy ι [0, 1, −p_b.y ι]
//   ∂q = σ_z² (j0 ∂j0 + j1 ∂j1) / q,   ∂c = −c (2q + σ_px) / (q (q + σ_px)) ∂q
//   ∂(j·e) = e0 ∂j0 + j0 ∂e0 + e1 ∂j1 + j1 ∂e1
//   ∂r_i = s (∂e_i − ∂c j_i (j·e) − c ∂j_i (j·e) − c j_i ∂(j·e))
//
// Zero where the point is at or behind camera b (the residual is 0 there). With `residuals`, also
// the residual, from the same intermediate values and by the same operations as
// ReprojectionResidual<double> (so bit for bit the same: the residual-only evaluation calls that).
inline void ReprojectionResidualGradients(const Eigen::Vector3d& p, const Eigen::Vector3d& dp,
                                          const Eigen::Vector2d& uv_b,
                                          const Eigen::Vector4d& intrinsics_b, double sqrt_weight,
                                          double pixel_sigma, double depth_sigma,
                                          Eigen::Matrix<double, 2, 3>* g_p,
                                          Eigen::Matrix<double, 2, 3>* g_d,
                                          double* residuals = nullptr) {
  g_p->setZero();
  g_d->setZero();
  if (p.z() < 1e-9) {
    if (residuals != nullptr) residuals[0] = residuals[1] = 0.0;
    return;
  }
  const double fx = intrinsics_b[0], fy = intrinsics_b[1];
  const double iz = 1.0 / p.z();
  // e = uv − uv_b as ProjectPinhole and ReprojectionResidual compute it.
  const double e0 = fx * p.x() / p.z() + intrinsics_b[2] - uv_b.x();
  const double e1 = fy * p.y() / p.z() + intrinsics_b[3] - uv_b.y();
  // Rows 0..5 of each 6-vector: ∂/∂p_b, then ∂/∂dp.
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  Vec6 de0, de1;
  de0 << fx * iz, 0.0, -fx * p.x() * iz * iz, 0.0, 0.0, 0.0;
  de1 << 0.0, fy * iz, -fy * p.y() * iz * iz, 0.0, 0.0, 0.0;
  const double s = sqrt_weight;
  if (depth_sigma <= 0.0) {
    if (residuals != nullptr) {
      residuals[0] = s * e0;
      residuals[1] = s * e1;
    }
    g_p->row(0) = s * de0.head<3>().transpose();
    g_p->row(1) = s * de1.head<3>().transpose();
    return;
  }
  const double j0 = fx * iz * (dp.x() - p.x() * iz * dp.z());
  const double j1 = fy * iz * (dp.y() - p.y() * iz * dp.z());
  Vec6 dj0, dj1;
  dj0 << -fx * iz * iz * dp.z(), 0.0, fx * iz * iz * (2.0 * p.x() * iz * dp.z() - dp.x()), fx * iz,
      0.0, -fx * p.x() * iz * iz;
  dj1 << 0.0, -fy * iz * iz * dp.z(), fy * iz * iz * (2.0 * p.y() * iz * dp.z() - dp.y()), 0.0,
      fy * iz, -fy * p.y() * iz * iz;
  const double sp = pixel_sigma, sz2 = depth_sigma * depth_sigma;
  const double q = std::sqrt(sp * sp + sz2 * (j0 * j0 + j1 * j1));
  const double c = sz2 / (q * (q + sp));
  const double je = j0 * e0 + j1 * e1;
  if (residuals != nullptr) {
    residuals[0] = s * (e0 - c * j0 * je);
    residuals[1] = s * (e1 - c * j1 * je);
  }
  const Vec6 dq = (sz2 / q) * (j0 * dj0 + j1 * dj1);
  const Vec6 dc = (-c * (2.0 * q + sp) / (q * (q + sp))) * dq;
  const Vec6 dje = e0 * dj0 + j0 * de0 + e1 * dj1 + j1 * de1;
  const Vec6 dr0 = s * (de0 - je * j0 * dc - c * je * dj0 - c * j0 * dje);
  const Vec6 dr1 = s * (de1 - je * j1 * dc - c * je * dj1 - c * j1 * dje);
  g_p->row(0) = dr0.head<3>().transpose();
  g_p->row(1) = dr1.head<3>().transpose();
  g_d->row(0) = dr0.tail<3>().transpose();
  g_d->row(1) = dr1.tail<3>().transpose();
}

// The residual at p_b and dp_b and, with `g_p` (and `g_d`), its gradients: ReprojectionResidual,
// or ReprojectionResidualGradients with the same residual bit for bit.
inline void ReprojectionResidualAt(const Eigen::Vector3d& p_b, const Eigen::Vector3d& dp_b,
                                   const Eigen::Vector2d& uv_b, const Eigen::Vector4d& intrinsics_b,
                                   double sqrt_weight, double pixel_sigma, double depth_sigma,
                                   double* residuals, Eigen::Matrix<double, 2, 3>* g_p,
                                   Eigen::Matrix<double, 2, 3>* g_d) {
  if (g_p == nullptr) {
    ReprojectionResidual(p_b, dp_b, uv_b, intrinsics_b, sqrt_weight, pixel_sigma, depth_sigma,
                         residuals);
  } else {
    ReprojectionResidualGradients(p_b, dp_b, uv_b, intrinsics_b, sqrt_weight, pixel_sigma,
                                  depth_sigma, g_p, g_d, residuals);
  }
}

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
    const bool whiten = depth_sigma > 0.0 && p_a_in_cam.z() > 0.0;
    Eigen::Matrix<T, 3, 1> dp_b = Eigen::Matrix<T, 3, 1>::Zero();
    if (whiten) {
      // ∂p_b/∂z_a = R_bᵀ R_a ray_a: the rotation part of the same map, applied to the ray.
      const Eigen::Map<const Eigen::Quaternion<T>> q_a(world_from_cam_a + 3);
      const Eigen::Map<const Eigen::Quaternion<T>> q_b(world_from_cam_b + 3);
      const Eigen::Matrix<T, 3, 1> ray_a = (p_a_in_cam / p_a_in_cam.z()).cast<T>();
      dp_b = q_b.conjugate() * (q_a * ray_a);
    }
    ReprojectionResidual(p_b_in_cam, dp_b, uv_b, intrinsics_b, sqrt_weight, pixel_sigma,
                         whiten ? depth_sigma : 0.0, residuals);
    return true;
  }

  const Eigen::Vector3d p_a_in_cam;
  const Eigen::Vector2d uv_b;
  const Eigen::Vector4d intrinsics_b;
  const double sqrt_weight;
  const double pixel_sigma;
  const double depth_sigma;
};

// What the observations of G from frame a into frame b share: b's pinhole intrinsics and the
// term's weights, as ReprojectionCostFunctor takes them.
struct ReprojectionModel {
  Eigen::Vector4d intrinsics_b = Eigen::Vector4d::Zero();  // fx fy cx cy (px)
  double sqrt_weight = 1.0;                                // s
  double pixel_sigma = 1.0;                                // σ_px (> 0)
  double depth_sigma = 0.0;                                // σ_z (m, ≥ 0; 0 = the plain error)
  bool operator==(const ReprojectionModel& o) const {
    return intrinsics_b == o.intrinsics_b && sqrt_weight == o.sqrt_weight &&
           pixel_sigma == o.pixel_sigma && depth_sigma == o.depth_sigma;
  }
};

// One observation of G in reprojection mode: a keypoint of frame a back-projected with its
// depth, and its match in frame b (40 bytes: a batch keeps them side by side).
struct ReprojectionObservation {
  Eigen::Vector3d p_a_in_cam;  // z_a · ray_a (m)
  Eigen::Vector2d uv_b;        // px
  // σ_z where the depth whitening applies (a point in front of camera a), else 0.
  double DepthSigma(const ReprojectionModel& model) const {
    return model.depth_sigma > 0.0 && p_a_in_cam.z() > 0.0 ? model.depth_sigma : 0.0;
  }
};

// ReprojectionCostFunctor with its Jacobians by the chain rule (what the builder uses: G is the
// largest term, and the functor's autodiff carries 14 derivatives through every operation).
// The residual depends on the poses only through p_b and dp_b (ReprojectionResidual):
//
//   p_w  = R_a p_a + t_a,   p_b = R_bᵀ (p_w − t_b),   v = R_a ray_a,   dp_b = R_bᵀ v
//   ∂r/∂t_a = G_p M,        ∂r/∂q_a = G_p M D_a + G_d M D_v,
//   ∂r/∂t_b = −G_p M,       ∂r/∂q_b = G_p Q_p + G_d Q_v,
//
// with G_p = ∂r/∂p_b and G_d = ∂r/∂dp_b (2 × 3, ReprojectionResidualGradients), M = ∂p_b/∂p_w,
// D_a = ∂(R_a p_a)/∂q_a, D_v = ∂v/∂q_a, Q_p = ∂p_b/∂q_b and Q_v = ∂dp_b/∂q_b
// (CamToWorldWithJacobian, WorldToCamWithJacobian: the ambient Jacobians autodiff gives, to
// rounding). `a`, `b`: the two 7-double poses; `jacobians`: null, or two 2 × 7 row-major
// blocks (either may be null). Always true (a point behind camera b gives r = 0).
inline bool EvaluateReprojection(const ReprojectionModel& model,
                                 const ReprojectionObservation& observation, const double* a,
                                 const double* b, double* residuals, double** jacobians) {
  const Eigen::Vector3d& p_a_in_cam = observation.p_a_in_cam;
  const double depth_sigma = observation.DepthSigma(model);
  const bool jac = jacobians != nullptr && (jacobians[0] != nullptr || jacobians[1] != nullptr);
  Eigen::Matrix<double, 3, 4> d_a, q_p, d_v, q_v;
  Eigen::Matrix3d m;
  const Eigen::Vector3d p_w = CamToWorldWithJacobian(a, p_a_in_cam, jac ? &d_a : nullptr);
  const Eigen::Vector3d p_b =
      WorldToCamWithJacobian(b, p_w, jac ? &m : nullptr, jac ? &q_p : nullptr);
  const bool whiten = depth_sigma > 0.0;
  Eigen::Vector3d dp_b = Eigen::Vector3d::Zero();
  if (whiten) {
    const double a_rotation[kPoseSize] = {0.0, 0.0, 0.0, a[3], a[4], a[5], a[6]};
    const double b_rotation[kPoseSize] = {0.0, 0.0, 0.0, b[3], b[4], b[5], b[6]};
    const Eigen::Vector3d v =
        CamToWorldWithJacobian(a_rotation, p_a_in_cam / p_a_in_cam.z(), jac ? &d_v : nullptr);
    dp_b = WorldToCamWithJacobian(b_rotation, v, nullptr, jac ? &q_v : nullptr);
  }
  // The residuals in doubles (the same with and without Jacobians), then their gradients.
  ReprojectionResidual(p_b, dp_b, observation.uv_b, model.intrinsics_b, model.sqrt_weight,
                       model.pixel_sigma, depth_sigma, residuals);
  if (!jac) return true;
  Eigen::Matrix<double, 2, 3> g_p, g_d;
  ReprojectionResidualGradients(p_b, dp_b, observation.uv_b, model.intrinsics_b, model.sqrt_weight,
                                model.pixel_sigma, depth_sigma, &g_p, &g_d);
  const Eigen::Matrix<double, 2, 3> g_p_m = g_p * m;
  if (jacobians[0] != nullptr) {
    Eigen::Map<Eigen::Matrix<double, 2, kPoseSize, Eigen::RowMajor>> j(jacobians[0]);
    j.leftCols<3>() = g_p_m;
    j.rightCols<4>() = g_p_m * d_a;
    if (whiten) j.rightCols<4>() += g_d * m * d_v;
  }
  if (jacobians[1] != nullptr) {
    Eigen::Map<Eigen::Matrix<double, 2, kPoseSize, Eigen::RowMajor>> j(jacobians[1]);
    j.leftCols<3>() = -g_p_m;
    j.rightCols<4>() = g_p * q_p;
    if (whiten) j.rightCols<4>() += g_d * q_v;
  }
  return true;
}

// The same residual from the poses as matrices, with `jacobian` null or its Jacobian in the
// tangent space of CreatePoseManifold(RefineMode::kFull) (pose.h), row-major: ∂r/∂[δ_a, δ_b]
// (2 × 12). With A = G_p R_bᵀ = ∂r/∂p_w and
// B = G_d R_bᵀ = ∂r/∂v (a row x times [u]× is x × u):
//
//   ∂r/∂δt_a = A,    ∂r/∂δθ_a = −2 (A × R_a p_a + B × v),
//   ∂r/∂δt_b = −A,   ∂r/∂δθ_b =  2 (A × (p_w − t_b) + B × v)          (row by row)
//
// r depends on the poses through b⁻¹ a alone: ∂r/∂δ_a = ∂r/∂δ_b E_ab (pose.h:
// RelativeTangentMap), which the compressed batches use (with EvaluateReprojectionInCameraB
// below). The residual is ReprojectionResidual's bit for bit, with or without the Jacobian.
inline void EvaluateReprojectionTangent(const ReprojectionModel& model,
                                        const ReprojectionObservation& observation,
                                        const PoseMatrix& a, const PoseMatrix& b, double* residuals,
                                        double* jacobian) {
  const Eigen::Vector3d& p_a_in_cam = observation.p_a_in_cam;
  const double depth_sigma = observation.DepthSigma(model);
  const Eigen::Vector3d r_a = a.rotation * p_a_in_cam;            // R_a p_a
  const Eigen::Vector3d d = r_a + a.translation - b.translation;  // p_w − t_b
  const Eigen::Vector3d p_b = b.rotation.transpose() * d;
  const bool whiten = depth_sigma > 0.0;
  Eigen::Vector3d v = Eigen::Vector3d::Zero(), dp_b = Eigen::Vector3d::Zero();
  if (whiten) {
    v = r_a / p_a_in_cam.z();  // R_a ray_a
    dp_b = b.rotation.transpose() * v;
  }
  Eigen::Matrix<double, 2, 3> g_p, g_d;
  ReprojectionResidualAt(p_b, dp_b, observation.uv_b, model.intrinsics_b, model.sqrt_weight,
                         model.pixel_sigma, depth_sigma, residuals,
                         jacobian != nullptr ? &g_p : nullptr, &g_d);
  if (jacobian == nullptr) return;
  const Eigen::Matrix<double, 2, 3> a_rows = g_p * b.rotation.transpose();
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector3d a_i = a_rows.row(i).transpose();
    Eigen::Vector3d b_v = Eigen::Vector3d::Zero();
    if (whiten) b_v = (g_d.row(i) * b.rotation.transpose()).transpose().cross(v);
    double* row = jacobian + i * 12;
    const Eigen::Vector3d b_theta = 2.0 * (a_i.cross(d) + b_v);
    for (int k = 0; k < 3; ++k) {
      row[6 + k] = -a_i[k];
      row[6 + 3 + k] = b_theta[k];
    }
    const Eigen::Vector3d a_theta = -2.0 * (a_i.cross(r_a) + b_v);
    for (int k = 0; k < 3; ++k) {
      row[k] = a_i[k];
      row[3 + k] = a_theta[k];
    }
  }
}

// The same residual from b⁻¹ a (what a compressed batch of one frame pair computes once), with
// `jacobian_in_b` null or 2 × 6 row-major: ∂r/∂δ_b (the tangent of pose b, as
// EvaluateReprojectionTangent) in camera b's axes, ∂r/∂δ_b = jacobian_in_b · diag(R_bᵀ, R_bᵀ).
// From the tangent form, with a_i = R_b g_pᵢᵀ, p_w − t_b = R_b p_b and v = R_b dp_b (a rotation
// keeps cross products):
//
//   p_b = R_ba p_a + t_ba,   dp_b = R_ba p_a / z_a
//   row i: [ −g_pᵢ,  2 (g_pᵢ × p_b + g_dᵢ × dp_b) ]
//
// so a batch sums its 6 × 6 model in camera b and turns it into pose b's tangent once.
inline void EvaluateReprojectionInCameraB(const ReprojectionModel& model,
                                          const ReprojectionObservation& observation,
                                          const RelativePose& b_from_a, double* residuals,
                                          double* jacobian_in_b) {
  const Eigen::Vector3d& p_a_in_cam = observation.p_a_in_cam;
  const double depth_sigma = observation.DepthSigma(model);
  const Eigen::Vector3d q = b_from_a.rotation * p_a_in_cam;  // R_ba p_a
  const Eigen::Vector3d p_b = q + b_from_a.translation;
  const bool whiten = depth_sigma > 0.0;
  const Eigen::Vector3d dp_b =
      whiten ? Eigen::Vector3d(q / p_a_in_cam.z()) : Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 2, 3> g_p, g_d;
  ReprojectionResidualAt(p_b, dp_b, observation.uv_b, model.intrinsics_b, model.sqrt_weight,
                         model.pixel_sigma, depth_sigma, residuals,
                         jacobian_in_b != nullptr ? &g_p : nullptr, &g_d);
  if (jacobian_in_b == nullptr) return;
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector3d g_p_i = g_p.row(i).transpose();
    Eigen::Vector3d theta = g_p_i.cross(p_b);
    if (whiten) theta += g_d.row(i).transpose().cross(dp_b);
    double* row = jacobian_in_b + 6 * i;
    for (int k = 0; k < 3; ++k) {
      row[k] = -g_p_i[k];
      row[3 + k] = 2.0 * theta[k];
    }
  }
}

// One observation as a cost function on [world_from_cam_a, world_from_cam_b] (the row form,
// batch_size = 1, and the tests); a compressed batch keeps ReprojectionObservations instead
// (BatchedCostFunction::AddReprojection).
class ReprojectionCostFunction final : public PoseTangentCostFunction {
 public:
  ReprojectionCostFunction(const ReprojectionModel& model,
                           const ReprojectionObservation& observation)
      : model_(model), observation_(observation) {
    set_num_residuals(2);
    *mutable_parameter_block_sizes() = {kPoseSize, kPoseSize};
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& p_a_in_cam, const Eigen::Vector2d& uv_b,
                                     const Eigen::Vector4d& intrinsics_b, double sqrt_weight,
                                     double pixel_sigma = 1.0, double depth_sigma = 0.0) {
    return new ReprojectionCostFunction({intrinsics_b, sqrt_weight, pixel_sigma, depth_sigma},
                                        {p_a_in_cam, uv_b});
  }

  const ReprojectionModel& model() const { return model_; }
  const ReprojectionObservation& observation() const { return observation_; }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    return EvaluateReprojection(model_, observation_, parameters[0], parameters[1], residuals,
                                jacobians);
  }

  bool EvaluateTangent(const PoseMatrix* poses, double* residuals,
                       double* jacobian) const override {
    EvaluateReprojectionTangent(model_, observation_, poses[0], poses[1], residuals, jacobian);
    return true;
  }

 private:
  const ReprojectionModel model_;
  const ReprojectionObservation observation_;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_REPROJECTION_H_
