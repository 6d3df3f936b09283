#include "bimcap/builder.h"

#include <cmath>

#include <Eigen/Eigenvalues>

#include "bimcap/cost_functions/pose_prior.h"
#include "bimcap/cost_functions/relative_pose.h"

namespace bimcap {

std::unique_ptr<ceres::LossFunction> CreateLoss(LossType type, double scale, double weight) {
  ceres::LossFunction* base = nullptr;
  switch (type) {
    case LossType::kNone: break;
    case LossType::kHuber: base = new ceres::HuberLoss(scale); break;
    case LossType::kCauchy: base = new ceres::CauchyLoss(scale); break;
    case LossType::kSoftL1: base = new ceres::SoftLOneLoss(scale); break;
    case LossType::kArctan: base = new ceres::ArctanLoss(scale); break;
    case LossType::kTukey: base = new ceres::TukeyLoss(scale); break;
  }
  if (weight == 1.0) return std::unique_ptr<ceres::LossFunction>(base);
  // ScaledLoss with a null base is the weighted identity, ρ(s) = weight · s.
  return std::make_unique<ceres::ScaledLoss>(base, weight, ceres::TAKE_OWNERSHIP);
}

ProblemBuilder::ProblemBuilder(const ProblemData& problem, const SolverOptions& options,
                               SolverState* state)
    : data_(problem), options_(options), state_(state) {
  pose_manifold_ = CreatePoseManifold(options.refine_mode);
  plane_manifold_ = CreatePlaneManifold();
}

bool ProblemBuilder::Prepare(int term, int64_t count, double sigma, int residual_size) {
  TermBlocks& t = terms_[term];
  t = TermBlocks();
  t.residual_size = residual_size;
  losses_[term].reset();
  const TermOptions& o = options_.term(term);
  if (!o.enabled || count == 0) return false;
  if (options_.weighting == Weighting::kPaper) {
    // The peers' λ · mean over N observations of ‖r‖²: λ / N per squared residual, plain L2.
    // Ceres minimises ½ Σ ‖s r‖², so s² = λ / N reproduces ½ × the paper's objective.
    if (o.paper_weight == 0.0) return false;
    t.sqrt_weight = std::sqrt(o.paper_weight / static_cast<double>(count));
  } else {
    if (o.weight == 0.0) return false;
    t.sqrt_weight = 1.0 / sigma;
    losses_[term] = CreateLoss(o.loss, o.loss_scale, o.weight);
  }
  t.active = true;
  return true;
}

void ProblemBuilder::Build() {
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  // The blocks added below are valid by construction (sizes fixed by the functors, distinct
  // parameter blocks per residual: ValidateProblem rejects a frame matched with itself), so
  // Ceres need not check each one again.
  problem_options.disable_all_safety_checks = true;
  problem_ = std::make_unique<ceres::Problem>(problem_options);
  ordering_.reset();
  has_landmarks_ = false;
  for (auto& t : terms_) t = TermBlocks();

  // 1. Residuals.
  if (options_.geometric_mode == GeometricMode::kLandmark) {
    AddLandmarks();
  } else {
    AddGeometric();
  }
  AddPlaneTerm(kTermF, data_.floor_frame, data_.floor_p_in_cam, data_.floor_plane, 0);
  AddPlaneTerm(kTermCe, data_.ceiling_frame, data_.ceiling_p_in_cam, data_.ceiling_plane, 1);
  AddSegmentTerm(kTermW, data_.wall_frame, data_.wall_p_in_cam, state_->wall_segment);
  AddSegmentTerm(kTermCo, data_.column_frame, data_.column_p_in_cam, state_->column_segment);
  AddPosePrior();  // it anchors only the poses the terms above put into the problem
  AddOdometry();

  // 2. Manifolds, 3. gauge. A pose without residuals is not in the problem and stays as it is.
  num_free_poses_ = 0;
  for (int64_t i = 0; i < data_.num_poses(); ++i) {
    double* pose = Pose(i);
    if (!problem_->HasParameterBlock(pose)) continue;
    if (data_.pose_fixed(i) != 0) {
      problem_->SetParameterBlockConstant(pose);
    } else {
      problem_->SetManifold(pose, pose_manifold_.get());
      ++num_free_poses_;
    }
  }
  for (int slot = 0; slot < 2; ++slot) {
    double* plane = state_->facap_planes.data() + 4 * slot;
    if (problem_->HasParameterBlock(plane)) problem_->SetManifold(plane, plane_manifold_.get());
  }

  // 4. Landmarks are eliminated first.
  if (has_landmarks_) {
    ordering_ = std::make_shared<ceres::ParameterBlockOrdering>();
    const int64_t num_points = data_.track_points.rows;
    for (int64_t j = 0; j < num_points; ++j) {
      double* x = state_->track_points.data() + 3 * j;
      if (problem_->HasParameterBlock(x)) ordering_->AddElementToGroup(x, 0);
    }
    for (int64_t i = 0; i < data_.num_poses(); ++i) {
      if (problem_->HasParameterBlock(Pose(i))) ordering_->AddElementToGroup(Pose(i), 1);
    }
    for (int slot = 0; slot < 2; ++slot) {
      double* plane = state_->facap_planes.data() + 4 * slot;
      if (problem_->HasParameterBlock(plane)) ordering_->AddElementToGroup(plane, 1);
    }
  }
}

void ProblemBuilder::AddPosePrior() {
  std::vector<int64_t> free;
  for (int64_t i = 0; i < data_.num_poses(); ++i) {
    if (data_.pose_fixed(i) == 0 && problem_->HasParameterBlock(Pose(i))) free.push_back(i);
  }
  // Never in PAPER weighting (the peers' objective); Prepare also leaves it out there because
  // Check() holds prior.paper_weight at 0. The functor whitens, so s = 1.
  if (options_.weighting == Weighting::kPaper) {
    terms_[kTermPrior] = TermBlocks();
    losses_[kTermPrior].reset();
    return;
  }
  if (!Prepare(kTermPrior, static_cast<int64_t>(free.size()), 1.0, 6)) return;
  TermBlocks& term = terms_[kTermPrior];
  ceres::LossFunction* loss = losses_[kTermPrior].get();
  const double sigma_t = options_.prior.sigma;
  const double sigma_r = options_.prior_sigma_r_deg * M_PI / 180.0;
  for (const int64_t i : free) {
    // The prior mean is the input pose (data_ is never written; the state is a copy).
    term.ids.push_back(problem_->AddResidualBlock(
        PosePriorCostFunctor::Create(data_.poses.row(i), sigma_t, sigma_r), loss, Pose(i)));
  }
  term.num_residual_blocks = static_cast<int64_t>(free.size());
}

void ProblemBuilder::AddOdometry() {
  // Never in PAPER weighting (Check() holds odometry.paper_weight at 0). The functor whitens.
  std::vector<int64_t> pairs;  // a of each consecutive pair (a, a + 1)
  for (int64_t a = 0; a + 1 < data_.num_poses(); ++a) {
    if (data_.pose_fixed(a) != 0 && data_.pose_fixed(a + 1) != 0) continue;
    pairs.push_back(a);
  }
  if (options_.weighting == Weighting::kPaper) {
    terms_[kTermOdometry] = TermBlocks();
    losses_[kTermOdometry].reset();
    return;
  }
  if (!Prepare(kTermOdometry, static_cast<int64_t>(pairs.size()), 1.0, 6)) return;
  TermBlocks& term = terms_[kTermOdometry];
  ceres::LossFunction* loss = losses_[kTermOdometry].get();
  const double sigma_t = options_.odometry.sigma;
  const double sigma_r = options_.odometry_sigma_r_deg * M_PI / 180.0;
  for (const int64_t a : pairs) {
    term.ids.push_back(problem_->AddResidualBlock(
        RelativePoseCostFunctor::Create(data_.poses.row(a), data_.poses.row(a + 1), sigma_t,
                                        sigma_r),
        loss, Pose(a), Pose(a + 1)));
  }
  term.num_residual_blocks = static_cast<int64_t>(pairs.size());
}

void ProblemBuilder::InitFacapPlanes() {
  const ArrayRef<int32_t>* frames[2] = {&data_.floor_frame, &data_.ceiling_frame};
  const ArrayRef<double>* points[2] = {&data_.floor_p_in_cam, &data_.ceiling_p_in_cam};
  for (int slot = 0; slot < 2; ++slot) {
    const int64_t n = frames[slot]->rows;
    state_->facap_plane_valid[slot] = false;
    for (int k = 0; k < 4; ++k) state_->facap_planes[4 * slot + k] = std::nan("");
    if (n < 3) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    std::vector<Eigen::Vector3d> world(n);
    for (int64_t i = 0; i < n; ++i) {
      const Eigen::Vector3d p((*points[slot])(i, 0), (*points[slot])(i, 1), (*points[slot])(i, 2));
      world[i] = CamToWorld(Pose((*frames[slot])(i)), p);
      mean += world[i];
    }
    mean /= static_cast<double>(n);
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (const auto& w : world) cov += (w - mean) * (w - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    Eigen::Vector3d normal = eig.eigenvectors().col(0);  // smallest eigenvalue
    if (normal.z() < 0) normal = -normal;                // a sign convention: normals point up
    state_->facap_planes[4 * slot + 0] = normal.x();
    state_->facap_planes[4 * slot + 1] = normal.y();
    state_->facap_planes[4 * slot + 2] = normal.z();
    state_->facap_planes[4 * slot + 3] = -normal.dot(mean);
    state_->facap_plane_valid[slot] = true;
  }
}

}  // namespace bimcap
