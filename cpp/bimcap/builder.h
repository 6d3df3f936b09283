// Builds the ceres::Problem for one Ceres run, in a fixed order:
//   1. residuals of each enabled term, in registry order (terms.h: G or its landmark form, the
//      landmark depth prior, F, Ce, W, Co, then the pose prior, which anchors only the poses the
//      terms before it reached, and the odometry), each added by its TermSpec::add with the
//      term's square-root weight inside the functor and the term's loss;
//   2. manifolds: poses (CreatePoseManifold(refine_mode)), FACaP planes (CreatePlaneManifold());
//   3. gauge: poses with pose_fixed = 1 held constant;
//   4. for landmark BA, an elimination ordering with the landmarks first (Schur complement).
// The builder owns the losses and manifolds (ceres::Problem is told not to), so that one set
// serves every residual of a term.
#ifndef BIMCAP_BUILDER_H_
#define BIMCAP_BUILDER_H_

#include <ceres/loss_function.h>
#include <ceres/manifold.h>
#include <ceres/ordered_groups.h>
#include <ceres/problem.h>

#include <map>
#include <memory>
#include <vector>

#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap {

// What the solver changes: poses, landmarks, the FACaP planes, the W / Co associations.
struct SolverState {
  std::vector<double> poses;         // (N, 7) flat, world_from_cam TUM order
  std::vector<double> track_points;  // (P, 3) flat
  // Per term (registry order): its FACaP plane [n, d] (terms with facap_plane) and whether it
  // was fitted, and its points' associated segments (terms with a segment_class; -1 = none).
  std::vector<double> facap_planes;          // (num terms, 4) flat
  std::vector<bool> facap_plane_valid;       // (num terms,)
  std::vector<std::vector<int>> segment_of;  // (num terms,) of (points,)
};

// Per term, what went into the problem.
struct TermBlocks {
  bool active = false;              // enabled and at least one residual
  double sqrt_weight = 0.0;         // s, the functor's scalar
  int64_t num_residual_blocks = 0;  // observations in the problem (N of the paper's mean)
  int64_t num_skipped = 0;          // observations left out (no depth, unassociated, ...)
  int residual_size = 0;
  // The term's Ceres residual blocks: one observation with the term's loss, or several that
  // share their parameter blocks in a BatchedCostFunction (no Ceres loss; see AddObservation).
  std::vector<ceres::ResidualBlockId> ids;
};

class ProblemBuilder {
 public:
  // `problem` and `options` must be valid (ValidateProblem, SolverOptions::Check) and outlive
  // the builder; `state` is the memory the parameter blocks point into.
  ProblemBuilder(const ProblemData& problem, const SolverOptions& options, SolverState* state);

  // Builds a fresh ceres::Problem from the current state (associations included).
  void Build();
  // After Build(): replaces the residual blocks of the association terms (W, Co: a
  // segment_class) with ones from the state's current association and keeps every other
  // term's blocks, so the problem is the one Build() would give (its blocks in another order,
  // so its sums to rounding). False, with nothing changed, where only Build() can do it: no
  // problem yet, landmarks, FACaP planes, or an association term that reaches a pose the terms
  // before it do not (the pose prior anchors the poses the terms before it reach).
  bool RebuildAssociationTerms();

  ceres::Problem& problem() { return *problem_; }
  const std::vector<TermBlocks>& terms() const { return terms_; }
  // The loss of a term's residual blocks (null: plain squares).
  const ceres::LossFunction* loss(int term) const { return losses_[term].get(); }
  // Elimination ordering for Schur solvers, or null when there are no landmarks.
  std::shared_ptr<ceres::ParameterBlockOrdering> ordering() const { return ordering_; }
  bool has_landmarks() const { return has_landmarks_; }
  int64_t num_free_poses() const { return num_free_poses_; }

  // Fits the FACaP plane of each term with facap_plane to the initial world points.
  void InitFacapPlanes();

  // ---- For the terms' add functions (TermSpec::add).
  const ProblemData& data() const { return data_; }
  const SolverOptions& options() const { return options_; }
  SolverState& state() { return *state_; }
  // Loss and square-root weight of a term for `count` observations (N of the paper's mean),
  // `sigma` the whitening scale (ROBUST), `residual_size` the functor's residual size; false:
  // leave the term out (disabled, no observation, zero weight, or not a paper term in PAPER
  // weighting).
  bool Prepare(int term, int64_t count, double sigma, int residual_size);
  TermBlocks& blocks(int term) { return terms_[term]; }
  // Adds one observation of the term being added (its cost function, owned from here on, on
  // `parameters`). The observations of a term that share their parameter blocks go into residual
  // blocks of up to options.batch_size observations (BatchedCostFunction, with the term's loss
  // inside); a lone one, or every one with batch_size = 1, into a block of its own with the term's
  // loss. The blocks are made by FlushObservations, once the term's add function has returned.
  void AddObservation(ceres::CostFunction* cost, std::vector<double*> parameters);
  // The same for one of G's reprojections from frame a into frame b, kept as plain data until
  // its batch is made (BatchedCostFunction::AddReprojection; a ReprojectionCostFunction where it
  // has a block of its own). The observations of one pair share `model`.
  void AddReprojection(const ReprojectionModel& model, const ReprojectionObservation& observation,
                       double* world_from_cam_a, double* world_from_cam_b);
  ceres::LossFunction* mutable_loss(int term) { return losses_[term].get(); }
  double* Pose(int64_t frame) { return state_->poses.data() + kPoseSize * frame; }
  double* TrackPoint(int64_t point) { return state_->track_points.data() + 3 * point; }
  double* FacapPlane(int term) { return state_->facap_planes.data() + 4 * term; }
  // A term that added landmark blocks: the solver eliminates them first (Schur).
  void MarkLandmarks() { has_landmarks_ = true; }

 private:
  // Groups the pending observations of `term` by parameter blocks and adds its residual blocks.
  void FlushObservations(int term);
  // The manifold Build() sets on a parameter block (poses, FACaP planes), null for the others.
  const ceres::Manifold* ManifoldOf(const double* block) const;

  struct PendingGroup {
    std::vector<double*> parameters;
    std::vector<std::pair<ceres::CostFunction*, int64_t>> samples;  // cost, index in the term
    // Or G's reprojections (a group holds one kind).
    ReprojectionModel model;
    std::vector<std::pair<ReprojectionObservation, int64_t>> reprojections;
  };
  // The pending group of `parameters` (a new one at the end if there is none).
  PendingGroup& Group(const std::vector<double*>& parameters);

  const ProblemData& data_;
  const SolverOptions& options_;
  SolverState* state_;
  std::vector<PendingGroup> pending_;
  std::map<std::vector<double*>, size_t> pending_index_;
  size_t last_group_ = 0;  // the group the last observation went to (consecutive ones share it)
  std::vector<double*> pair_key_;  // AddReprojection's key, kept to spare an allocation a call
  int64_t pending_count_ = 0;
  std::unique_ptr<ceres::Problem> problem_;
  std::vector<TermBlocks> terms_;
  std::vector<std::unique_ptr<ceres::LossFunction>> losses_;
  std::unique_ptr<ceres::Manifold> pose_manifold_;
  std::unique_ptr<ceres::Manifold> plane_manifold_;
  std::shared_ptr<ceres::ParameterBlockOrdering> ordering_;
  // Whether RebuildAssociationTerms may run on the current problem, and which poses the terms
  // before the first association term reached (per frame, 1 = in the problem).
  bool can_rebuild_associations_ = false;
  std::vector<char> reached_before_associations_;
  bool has_landmarks_ = false;
  int64_t num_free_poses_ = 0;
};

std::unique_ptr<ceres::LossFunction> CreateLoss(LossType type, double scale, double weight);

}  // namespace bimcap

#endif  // BIMCAP_BUILDER_H_
