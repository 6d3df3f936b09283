// Builds the ceres::Problem for one Ceres run, in a fixed order:
//   1. residuals of each enabled term (G or its landmark form + depth prior, F, Ce, W, Co), each
//      with the term's square-root weight inside the functor and the term's loss; then (ROBUST
//      weighting only) one pose prior per free pose those terms reached, centred on the input
//      pose, and one odometry residual per pair of consecutive frames (not both fixed);
//   2. manifolds: poses (CreatePoseManifold(refine_mode)), FACaP planes (CreatePlaneManifold());
//   3. gauge: poses with pose_fixed = 1 held constant;
//   4. for landmark BA, an elimination ordering with the landmarks first (Schur complement).
// The builder owns the losses and manifolds (ceres::Problem is told not to), so that one set
// serves every residual of a term.
#ifndef BIMCAP_BUILDER_H_
#define BIMCAP_BUILDER_H_

#include <array>
#include <memory>
#include <vector>

#include <ceres/loss_function.h>
#include <ceres/manifold.h>
#include <ceres/ordered_groups.h>
#include <ceres/problem.h>

#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap {

// What the solver changes: poses, landmarks, the FACaP planes, the W / Co associations.
struct SolverState {
  std::vector<double> poses;           // (N, 7) flat, world_from_cam TUM order
  std::vector<double> track_points;    // (P, 3) flat
  std::array<double, 8> facap_planes;  // floor [0:4], ceiling [4:8]: n, d
  std::array<bool, 2> facap_plane_valid{false, false};
  std::vector<int> wall_segment;       // (W,) associated segment or -1
  std::vector<int> column_segment;     // (W',)
};

// Per term, what went into the problem.
struct TermBlocks {
  bool active = false;                 // enabled and at least one residual
  double sqrt_weight = 0.0;            // s, the functor's scalar
  int64_t num_residual_blocks = 0;     // observations in the problem (N of the paper's mean)
  int64_t num_skipped = 0;             // observations left out (no depth, unassociated, ...)
  int residual_size = 0;
  std::vector<ceres::ResidualBlockId> ids;
};

class ProblemBuilder {
 public:
  // `problem` and `options` must be valid (ValidateProblem, SolverOptions::Check) and outlive
  // the builder; `state` is the memory the parameter blocks point into.
  ProblemBuilder(const ProblemData& problem, const SolverOptions& options, SolverState* state);

  // Builds a fresh ceres::Problem from the current state (associations included).
  void Build();

  ceres::Problem& problem() { return *problem_; }
  const std::array<TermBlocks, kNumTerms>& terms() const { return terms_; }
  // The loss of a term's residual blocks (null: plain squares).
  const ceres::LossFunction* loss(int term) const { return losses_[term].get(); }
  // Elimination ordering for Schur solvers, or null when there are no landmarks.
  std::shared_ptr<ceres::ParameterBlockOrdering> ordering() const { return ordering_; }
  bool has_landmarks() const { return has_landmarks_; }
  int64_t num_free_poses() const { return num_free_poses_; }

  // Fits the FACaP floor / ceiling planes to the initial world points of each term.
  void InitFacapPlanes();

 private:
  void AddGeometric();
  void AddLandmarks();
  void AddPlaneTerm(int term, const ArrayRef<int32_t>& frame, const ArrayRef<double>& p_in_cam,
                    const ArrayRef<int32_t>& plane, int facap_slot);
  void AddSegmentTerm(int term, const ArrayRef<int32_t>& frame, const ArrayRef<double>& p_in_cam,
                      const std::vector<int>& association);
  void AddPosePrior();
  void AddOdometry();
  // Loss and square-root weight of a term for `count` observations; false = leave it out.
  bool Prepare(int term, int64_t count, double sigma, int residual_size);
  double* Pose(int64_t frame) { return state_->poses.data() + kPoseSize * frame; }

  const ProblemData& data_;
  const SolverOptions& options_;
  SolverState* state_;
  std::unique_ptr<ceres::Problem> problem_;
  std::array<TermBlocks, kNumTerms> terms_;
  std::array<std::unique_ptr<ceres::LossFunction>, kNumTerms> losses_;
  std::unique_ptr<ceres::Manifold> pose_manifold_;
  std::unique_ptr<ceres::Manifold> plane_manifold_;
  std::shared_ptr<ceres::ParameterBlockOrdering> ordering_;
  bool has_landmarks_ = false;
  int64_t num_free_poses_ = 0;
};

std::unique_ptr<ceres::LossFunction> CreateLoss(LossType type, double scale, double weight);

}  // namespace bimcap

#endif  // BIMCAP_BUILDER_H_
