#include "bimcap/builder.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include "bimcap/cost_functions/batched.h"
#include "bimcap/terms.h"

namespace bimcap {

std::unique_ptr<ceres::LossFunction> CreateLoss(LossType type, double scale, double weight) {
  ceres::LossFunction* base = nullptr;
  switch (type) {
    case LossType::kNone:
      break;
    case LossType::kHuber:
      base = new ceres::HuberLoss(scale);
      break;
    case LossType::kCauchy:
      base = new ceres::CauchyLoss(scale);
      break;
    case LossType::kSoftL1:
      base = new ceres::SoftLOneLoss(scale);
      break;
    case LossType::kArctan:
      base = new ceres::ArctanLoss(scale);
      break;
    case LossType::kTukey:
      base = new ceres::TukeyLoss(scale);
      break;
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
  const size_t num_terms = Terms().size();
  terms_.resize(num_terms);
  losses_.resize(num_terms);
  state_->facap_planes.resize(4 * num_terms, std::nan(""));
  state_->facap_plane_valid.resize(num_terms, false);
  state_->segment_of.resize(num_terms);
}

bool ProblemBuilder::Prepare(int term, int64_t count, double sigma, int residual_size) {
  TermBlocks& t = terms_[term];
  t = TermBlocks();
  t.residual_size = residual_size;
  losses_[term].reset();
  const TermOptions& o = options_.term(term);
  if (!o.enabled || count == 0) return false;
  if (options_.weighting == Weighting::kPaper) {
    if (!Terms()[term].paper_term) return false;  // the pose prior and the odometry
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
  // RebuildAssociationTerms removes the association terms' blocks between rounds.
  problem_options.enable_fast_removal = true;
  problem_ = std::make_unique<ceres::Problem>(problem_options);
  ordering_.reset();
  has_landmarks_ = false;
  for (auto& t : terms_) t = TermBlocks();

  // 1. Residuals, term by term in registry order. RebuildAssociationTerms needs the association
  // terms (W, Co) one after the other before the pose prior, and no pose that only they reach.
  int first_association = -1, last_association = -1;
  for (int t = 0; t < NumTerms(); ++t) {
    if (Terms()[t].segment_class == 0) continue;
    if (first_association < 0) first_association = t;
    last_association = t;
  }
  const auto poses_in_problem = [&]() {
    std::vector<char> in(data_.num_poses(), 0);
    for (int64_t i = 0; i < data_.num_poses(); ++i) in[i] = problem_->HasParameterBlock(Pose(i));
    return in;
  };
  can_rebuild_associations_ = first_association >= 0 && options_.plane_mode != PlaneMode::kFacap;
  for (int t = 0; t < NumTerms(); ++t) {
    if (t == first_association) reached_before_associations_ = poses_in_problem();
    if (t > first_association && t <= last_association && Terms()[t].segment_class == 0) {
      can_rebuild_associations_ = false;  // another term between them
    }
    Terms()[t].add(*this, t);
    FlushObservations(t);
    if (t == last_association && poses_in_problem() != reached_before_associations_) {
      can_rebuild_associations_ = false;
    }
  }
  const int prior = TermIndex("prior");
  if (has_landmarks_ || (prior >= 0 && prior < last_association)) {
    can_rebuild_associations_ = false;
  }

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
  for (int t = 0; t < NumTerms(); ++t) {
    double* plane = FacapPlane(t);
    if (problem_->HasParameterBlock(plane)) problem_->SetManifold(plane, plane_manifold_.get());
  }

  // 4. Landmarks are eliminated first.
  if (has_landmarks_) {
    ordering_ = std::make_shared<ceres::ParameterBlockOrdering>();
    const int64_t num_points = static_cast<int64_t>(state_->track_points.size() / 3);
    for (int64_t j = 0; j < num_points; ++j) {
      double* x = state_->track_points.data() + 3 * j;
      if (problem_->HasParameterBlock(x)) ordering_->AddElementToGroup(x, 0);
    }
    for (int64_t i = 0; i < data_.num_poses(); ++i) {
      if (problem_->HasParameterBlock(Pose(i))) ordering_->AddElementToGroup(Pose(i), 1);
    }
    for (int t = 0; t < NumTerms(); ++t) {
      double* plane = FacapPlane(t);
      if (problem_->HasParameterBlock(plane)) ordering_->AddElementToGroup(plane, 1);
    }
  }
}

ProblemBuilder::PendingGroup& ProblemBuilder::Group(const std::vector<double*>& parameters) {
  if (last_group_ < pending_.size() && pending_[last_group_].parameters == parameters)
    return pending_[last_group_];
  const auto [it, inserted] = pending_index_.try_emplace(parameters, pending_.size());
  if (inserted) {
    pending_.emplace_back();
    pending_.back().parameters = parameters;
  }
  last_group_ = it->second;
  return pending_[last_group_];
}

void ProblemBuilder::AddObservation(ceres::CostFunction* cost, std::vector<double*> parameters) {
  PendingGroup& group = Group(parameters);
  if (!group.reprojections.empty())
    throw std::logic_error("ProblemBuilder: a cost function among reprojections");
  group.samples.emplace_back(cost, pending_count_++);
}

void ProblemBuilder::AddReprojection(const ReprojectionModel& model,
                                     const ReprojectionObservation& observation,
                                     double* world_from_cam_a, double* world_from_cam_b) {
  pair_key_.assign({world_from_cam_a, world_from_cam_b});
  PendingGroup& group = Group(pair_key_);
  if (!group.samples.empty() || (!group.reprojections.empty() && !(group.model == model)))
    throw std::logic_error("ProblemBuilder: a reprojection of another kind or model");
  group.model = model;
  group.reprojections.emplace_back(observation, pending_count_++);
}

void ProblemBuilder::FlushObservations(int term) {
  TermBlocks& blocks = terms_[term];
  ceres::LossFunction* loss = losses_[term].get();
  const size_t batch = static_cast<size_t>(std::max(1, options_.batch_size));
  if (batch == 1) {
    // Reprojections as cost functions of their own.
    for (PendingGroup& group : pending_) {
      for (const auto& [observation, index] : group.reprojections)
        group.samples.emplace_back(new ReprojectionCostFunction(group.model, observation), index);
      group.reprojections.clear();
    }
    // One block per observation with the term's loss, in the order they were added.
    std::vector<std::pair<int64_t, size_t>> order;  // index, group
    for (size_t g = 0; g < pending_.size(); ++g) {
      for (const auto& sample : pending_[g].samples) order.emplace_back(sample.second, g);
    }
    std::sort(order.begin(), order.end());
    std::vector<size_t> next(pending_.size(), 0);
    for (const auto& [index, g] : order) {
      ceres::CostFunction* cost = pending_[g].samples[next[g]++].first;
      blocks.ids.push_back(problem_->AddResidualBlock(cost, loss, pending_[g].parameters));
    }
  } else {
    for (const PendingGroup& group : pending_) {
      const auto& samples = group.samples;
      const auto& reprojections = group.reprojections;
      const size_t count = samples.size() + reprojections.size();
      // The manifold Build() sets on each parameter block (a constant pose's is never used).
      std::vector<const ceres::Manifold*> manifolds;
      for (const double* block : group.parameters) manifolds.push_back(ManifoldOf(block));
      // Chunks of at most `batch`, as even as the count allows.
      const size_t chunks = (count + batch - 1) / batch;
      for (size_t c = 0; c < chunks; ++c) {
        const size_t begin = count * c / chunks;
        const size_t end = count * (c + 1) / chunks;
        auto* batched = new BatchedCostFunction(loss, blocks.residual_size, manifolds,
                                                options_.compress_batches);
        for (size_t i = begin; i < end; ++i) {
          if (reprojections.empty()) {
            batched->Add(std::unique_ptr<ceres::CostFunction>(samples[i].first), samples[i].second);
          } else {
            batched->AddReprojection(group.model, reprojections[i].first, reprojections[i].second);
          }
        }
        blocks.ids.push_back(problem_->AddResidualBlock(batched, nullptr, group.parameters));
      }
    }
  }
  pending_.clear();
  pending_index_.clear();
  last_group_ = 0;
  pending_count_ = 0;
}

bool ProblemBuilder::RebuildAssociationTerms() {
  if (problem_ == nullptr || !can_rebuild_associations_) return false;
  // The new association must reach only poses that were in the problem before it.
  for (int t = 0; t < NumTerms(); ++t) {
    const TermSpec& spec = Terms()[t];
    if (spec.segment_class == 0) continue;
    const ArrayRef<int32_t> frame = data_.I32(std::string(spec.points) + "_frame");
    const std::vector<int>& association = state_->segment_of[t];
    if (static_cast<int64_t>(association.size()) != frame.rows) continue;  // not associated
    for (int64_t i = 0; i < frame.rows; ++i) {
      if (association[i] >= 0 && reached_before_associations_[frame(i)] == 0) return false;
    }
  }
  for (int t = 0; t < NumTerms(); ++t) {
    if (Terms()[t].segment_class == 0) continue;
    for (const ceres::ResidualBlockId id : terms_[t].ids) problem_->RemoveResidualBlock(id);
    terms_[t] = TermBlocks();
    Terms()[t].add(*this, t);
    FlushObservations(t);
  }
  return true;
}

const ceres::Manifold* ProblemBuilder::ManifoldOf(const double* block) const {
  const double* poses = state_->poses.data();
  if (block >= poses && block < poses + state_->poses.size()) return pose_manifold_.get();
  const double* planes = state_->facap_planes.data();
  if (block >= planes && block < planes + state_->facap_planes.size()) return plane_manifold_.get();
  return nullptr;
}

void ProblemBuilder::InitFacapPlanes() {
  for (int t = 0; t < NumTerms(); ++t) {
    const TermSpec& spec = Terms()[t];
    state_->facap_plane_valid[t] = false;
    for (int k = 0; k < 4; ++k) FacapPlane(t)[k] = std::nan("");
    if (!spec.facap_plane) continue;
    const ArrayRef<int32_t> frames = data_.I32(std::string(spec.points) + "_frame");
    const ArrayRef<double> points = data_.F64(std::string(spec.points) + "_p_in_cam");
    const int64_t n = frames.rows;
    if (n < 3) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    std::vector<Eigen::Vector3d> world(n);
    for (int64_t i = 0; i < n; ++i) {
      world[i] =
          CamToWorld(Pose(frames(i)), Eigen::Vector3d(points(i, 0), points(i, 1), points(i, 2)));
      mean += world[i];
    }
    mean /= static_cast<double>(n);
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (const auto& w : world) cov += (w - mean) * (w - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    Eigen::Vector3d normal = eig.eigenvectors().col(0);  // smallest eigenvalue
    if (normal.z() < 0) normal = -normal;                // a sign convention: normals point up
    double* plane = FacapPlane(t);
    plane[0] = normal.x();
    plane[1] = normal.y();
    plane[2] = normal.z();
    plane[3] = -normal.dot(mean);
    state_->facap_plane_valid[t] = true;
  }
}

}  // namespace bimcap
