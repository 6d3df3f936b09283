// Observations on pose blocks that write their Jacobians in the poses' tangent space directly.
#ifndef BIMCAP_COST_FUNCTIONS_POSE_TANGENT_H_
#define BIMCAP_COST_FUNCTIONS_POSE_TANGENT_H_

#include <ceres/cost_function.h>

#include "bimcap/pose.h"

namespace bimcap {

// An observation whose parameter blocks are all 7-double poses, which can also evaluate itself
// from the poses as matrices (PoseMatrix, made once for all the observations of a batch) and
// write its Jacobian in the tangent space of CreatePoseManifold(RefineMode::kFull), [δt, δθ] per
// pose (pose.h: IsFullPoseManifold). That is what Ceres makes of the ambient Jacobian (times the
// manifold's Plus Jacobian), to rounding, for a fraction of the work;
// BatchedCostFunction's compressed form uses it where every block is on that manifold.
class PoseTangentCostFunction : public ceres::CostFunction {
 public:
  // `poses`: one per parameter block; `residuals`: num_residuals() values; `jacobian`: null, or
  // num_residuals() × 6 · (parameter blocks), row-major. False: not evaluable (as Evaluate).
  virtual bool EvaluateTangent(const PoseMatrix* poses, double* residuals,
                               double* jacobian) const = 0;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_POSE_TANGENT_H_
