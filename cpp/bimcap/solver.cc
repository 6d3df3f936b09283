#include "bimcap/solver.h"

#include <ceres/cost_function.h>
#include <ceres/covariance.h>
#include <ceres/solver.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bimcap/builder.h"
#include "bimcap/cost_functions/batched.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

using Clock = std::chrono::steady_clock;

ceres::LinearSolverType ChooseLinearSolver(const SolverOptions& options, bool landmarks) {
  switch (options.linear_solver) {
    case LinearSolver::kDenseQr:
      return ceres::DENSE_QR;
    case LinearSolver::kDenseNormalCholesky:
      return ceres::DENSE_NORMAL_CHOLESKY;
    case LinearSolver::kSparseNormalCholesky:
      return ceres::SPARSE_NORMAL_CHOLESKY;
    case LinearSolver::kDenseSchur:
      return ceres::DENSE_SCHUR;
    case LinearSolver::kSparseSchur:
      return ceres::SPARSE_SCHUR;
    case LinearSolver::kIterativeSchur:
      return ceres::ITERATIVE_SCHUR;
    case LinearSolver::kAuto:
    default:
      return landmarks ? ceres::SPARSE_SCHUR : ceres::SPARSE_NORMAL_CHOLESKY;
  }
}

struct TermCosts {
  double cost = 0.0;    // with loss
  double sq_sum = 0.0;  // Σ ‖r‖² of the raw residuals
};

// The residual blocks whose residual or cost is not finite (NaN / Inf), and the first of them.
struct NonFinite {
  int term = -1;                // -1: every active term is finite
  int64_t block = -1;           // index of the first bad block within its term
  int64_t term_blocks = 0;      // blocks of that term
  int64_t count = 0;            // bad blocks over all terms
  std::vector<int64_t> frames;  // the poses the first bad block depends on
  std::vector<int64_t> points;  // the landmarks it depends on
  bool found() const { return term >= 0; }
};

constexpr double kInf = std::numeric_limits<double>::infinity();

// Calls visit(residuals, ok, index, parameters) for each observation of active term `t`, with
// its raw residuals (the term's residual_size values, no loss; ok: its cost function succeeded),
// its index in the term and its parameter blocks, straight through the observation's own cost
// function, batched or not (no Jacobians; Ceres' evaluation would log a page per bad block).
template <typename Visit>
void ForEachObservation(ProblemBuilder& builder, int t, Visit visit) {
  const TermBlocks& term = builder.terms()[t];
  std::vector<double> residuals;
  std::vector<double*> parameters;
  int64_t index = 0;  // of the next unbatched block
  for (const ceres::ResidualBlockId id : term.ids) {
    const ceres::CostFunction* cost_function =
        builder.problem().GetCostFunctionForResidualBlock(id);
    builder.problem().GetParameterBlocksForResidualBlock(id, &parameters);
    const auto* batched = dynamic_cast<const BatchedCostFunction*>(cost_function);
    if (batched == nullptr) {
      residuals.assign(static_cast<size_t>(cost_function->num_residuals()), 0.0);
      const bool ok = cost_function->Evaluate(parameters.data(), residuals.data(), nullptr);
      visit(residuals, ok, index++, parameters);
      continue;
    }
    for (int i = 0; i < batched->num_samples(); ++i) {
      residuals.assign(static_cast<size_t>(batched->residuals_per_sample()), 0.0);
      const bool ok = batched->EvaluateSample(i, parameters.data(), residuals.data());
      visit(residuals, ok, batched->sample_index(i), parameters);
    }
  }
}

// Evaluates every observation of the active terms and reports those whose residual, or whose
// cost ½ ρ(‖r‖²) under the term's loss, is not finite. One pass over the residuals: cheaper
// than a single Ceres iteration (about 1 % of a solve).
NonFinite FindNonFinite(ProblemBuilder& builder, const SolverState& state) {
  NonFinite out;
  const double* poses_begin = state.poses.data();
  const double* poses_end = poses_begin + state.poses.size();
  const double* points_begin = state.track_points.data();
  const double* points_end = points_begin + state.track_points.size();
  for (int t = 0; t < NumTerms(); ++t) {
    const TermBlocks& term = builder.terms()[t];
    if (!term.active) continue;
    const ceres::LossFunction* loss = builder.loss(t);
    // The first bad observation of the term by index (batches group them by frame).
    bool first_term = !out.found();
    ForEachObservation(builder, t,
                       [&](const std::vector<double>& residuals, bool ok, int64_t index,
                           const std::vector<double*>& parameters) {
                         double sq = 0.0;
                         for (const double r : residuals) {
                           ok = ok && std::isfinite(r);
                           sq += r * r;
                         }
                         double rho[3] = {sq, 1.0, 0.0};
                         if (ok && loss != nullptr) loss->Evaluate(sq, rho);
                         if (ok && std::isfinite(0.5 * rho[0])) return;
                         ++out.count;
                         if (!first_term || (out.term == t && index >= out.block)) return;
                         out.term = t;
                         out.block = index;
                         out.term_blocks = term.num_residual_blocks;
                         out.frames.clear();
                         out.points.clear();
                         for (const double* p : parameters) {
                           if (p >= poses_begin && p < poses_end) {
                             out.frames.push_back((p - poses_begin) / kPoseSize);
                           } else if (p >= points_begin && p < points_end) {
                             out.points.push_back((p - points_begin) / 3);
                           }
                         }
                       });
  }
  return out;
}

std::string TermLabel(int term) {
  return std::string(TermName(term)) + " (" + Terms()[term].what + ")";
}

// "initial cost is not finite: term F (floor), residual block 12 of 300 (frame 3) ..."
std::string DescribeNonFinite(const NonFinite& bad, const char* when) {
  std::ostringstream o;
  o << when << " cost is not finite: term " << TermLabel(bad.term) << ", residual block "
    << bad.block << " of " << bad.term_blocks;
  if (!bad.frames.empty() || !bad.points.empty()) {
    o << " (";
    const char* sep = "";
    if (!bad.frames.empty()) {
      o << (bad.frames.size() == 1 ? "frame " : "frames ");
      for (size_t i = 0; i < bad.frames.size(); ++i) o << (i ? ", " : "") << bad.frames[i];
      sep = "; ";
    }
    if (!bad.points.empty()) {
      o << sep << "track point " << bad.points.front();
    }
    o << ")";
  }
  o << ", " << bad.count << " non-finite block" << (bad.count == 1 ? "" : "s")
    << " in all; check that term's inputs (poses, cameras, observations) and its sigma / "
       "weight for values that overflow";
  return o.str();
}

// Per-term cost (with the loss) and raw squared sum (without it, divided by s²), from one
// evaluation of the term's observations: cost = ½ Σ_observations ρ(‖r‖²), as Ceres computes
// it. A term whose evaluation fails (a non-finite residual) gets an infinite cost. The blocks
// are evaluated on `num_threads` threads, each observation's ‖r‖² and ρ kept, and summed in
// ForEachObservation's order: the same sums whatever the number of threads.
std::vector<TermCosts> EvaluateTerms(ProblemBuilder& builder, int num_threads) {
  std::vector<TermCosts> out(Terms().size());
  std::vector<double> sq, rho;
  std::vector<char> ok;
  for (int t = 0; t < NumTerms(); ++t) {
    const TermBlocks& term = builder.terms()[t];
    if (!term.active || term.ids.empty()) continue;
    const ceres::LossFunction* loss = builder.loss(t);
    // Each block's first observation in the term's order.
    const size_t num_blocks = term.ids.size();
    std::vector<int64_t> first(num_blocks + 1, 0);
    for (size_t k = 0; k < num_blocks; ++k) {
      const auto* batched = dynamic_cast<const BatchedCostFunction*>(
          builder.problem().GetCostFunctionForResidualBlock(term.ids[k]));
      first[k + 1] = first[k] + (batched != nullptr ? batched->num_samples() : 1);
    }
    const int64_t n = first.back();
    sq.assign(n, 0.0);
    rho.assign(n, 0.0);
    ok.assign(n, 0);
    const auto evaluate = [&](size_t begin, size_t end) {
      std::vector<double> residuals;
      std::vector<double*> parameters;
      for (size_t k = begin; k < end; ++k) {
        const ceres::CostFunction* cost_function =
            builder.problem().GetCostFunctionForResidualBlock(term.ids[k]);
        builder.problem().GetParameterBlocksForResidualBlock(term.ids[k], &parameters);
        const auto* batched = dynamic_cast<const BatchedCostFunction*>(cost_function);
        for (int64_t i = first[k]; i < first[k + 1]; ++i) {
          const int sample = static_cast<int>(i - first[k]);
          residuals.assign(
              batched != nullptr ? batched->residuals_per_sample() : cost_function->num_residuals(),
              0.0);
          const bool evaluated =
              batched != nullptr
                  ? batched->EvaluateSample(sample, parameters.data(), residuals.data())
                  : cost_function->Evaluate(parameters.data(), residuals.data(), nullptr);
          double s = 0.0;
          for (const double r : residuals) s += r * r;
          sq[i] = s;
          ok[i] = evaluated && std::isfinite(s);
          if (loss == nullptr) continue;
          double value[3];
          loss->Evaluate(s, value);
          rho[i] = value[0];
        }
      }
    };
    // Contiguous ranges of blocks, about as many observations each.
    const int threads =
        static_cast<int>(std::clamp<int64_t>(std::min<int64_t>(num_threads, n / 10000), 1, 64));
    std::vector<std::thread> workers;
    size_t begin = 0;
    for (int w = 0; w < threads; ++w) {
      size_t end = begin;
      const int64_t until = n * (w + 1) / threads;
      while (end < num_blocks && first[end + 1] <= until) ++end;
      if (w + 1 == threads) end = num_blocks;
      if (w + 1 == threads) {
        evaluate(begin, end);
      } else {
        workers.emplace_back(evaluate, begin, end);
      }
      begin = end;
    }
    for (std::thread& worker : workers) worker.join();
    double plain = 0.0, cost = 0.0;
    bool all_ok = true;
    for (int64_t i = 0; i < n; ++i) {
      all_ok = all_ok && ok[i] != 0;
      plain += 0.5 * sq[i];
      cost += 0.5 * rho[i];
    }
    if (!all_ok) {
      out[t].cost = kInf;
      out[t].sq_sum = kInf;
      continue;
    }
    out[t].sq_sum = 2.0 * plain / (term.sqrt_weight * term.sqrt_weight);
    out[t].cost = loss == nullptr ? plain : cost;
  }
  return out;
}

void Record(const std::vector<TermCosts>& costs, const ProblemBuilder& builder,
            const SolverOptions& options, bool initial, Summary* summary) {
  double total = 0.0, paper = 0.0;
  for (int t = 0; t < NumTerms(); ++t) {
    const TermBlocks& blocks = builder.terms()[t];
    TermSummary& ts = summary->terms[t];
    const double n = static_cast<double>(blocks.num_residual_blocks);
    const double rms =
        blocks.active && n > 0 ? std::sqrt(costs[t].sq_sum / (n * blocks.residual_size)) : 0.0;
    const double share =
        blocks.active && n > 0 ? options.term(t).paper_weight * costs[t].sq_sum / n : 0.0;
    total += costs[t].cost;
    paper += share;
    if (initial) {
      ts.initial_cost = costs[t].cost;
      ts.initial_rms = rms;
      ts.initial_paper_objective = share;
    } else {
      ts.final_cost = costs[t].cost;
      ts.final_rms = rms;
      ts.final_paper_objective = share;
      ts.active = blocks.active;
      ts.num_residual_blocks = blocks.num_residual_blocks;
      ts.num_residuals = blocks.num_residual_blocks * blocks.residual_size;
      ts.num_skipped = blocks.num_skipped;
      ts.sqrt_weight = blocks.sqrt_weight;
    }
  }
  if (initial) {
    summary->initial_cost = total;
    summary->initial_paper_objective = paper;
  } else {
    summary->final_cost = total;
    summary->final_paper_objective = paper;
  }
}

void NormalizeQuaternions(std::vector<double>* poses) {
  for (size_t i = 0; i + kPoseSize <= poses->size(); i += kPoseSize) {
    double* q = poses->data() + i + 3;
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int k = 0; k < 4; ++k) q[k] /= norm;
  }
}

void ComputeCovariance(ProblemBuilder& builder, const ProblemData& data,
                       const SolverOptions& options, SolverState* state, SolveResult* result) {
  Summary& summary = result->summary;
  summary.covariance_requested = true;
  ceres::Covariance::Options cov_options;
  cov_options.num_threads = options.num_threads;
  cov_options.algorithm_type = ceres::SPARSE_QR;
  ceres::Covariance covariance(cov_options);
  std::vector<std::pair<const double*, const double*>> blocks;
  const int64_t n = data.num_poses();
  for (int64_t i = 0; i < n; ++i) {
    const double* pose = state->poses.data() + kPoseSize * i;
    if (builder.problem().HasParameterBlock(pose) && data.pose_fixed(i) == 0) {
      blocks.emplace_back(pose, pose);
    }
  }
  result->covariance.assign(n * 36, 0.0);
  if (blocks.empty()) {
    summary.covariance_ok = true;
    summary.covariance_message = "no free poses";
    return;
  }
  if (!covariance.Compute(blocks, &builder.problem())) {
    summary.covariance_ok = false;
    summary.covariance_message =
        "ceres::Covariance failed (rank-deficient: is the gauge fixed? see pose_fixed)";
    result->covariance.clear();
    return;
  }
  const int tangent = builder.problem().ParameterBlockTangentSize(blocks.front().first);
  std::vector<double> block(tangent * tangent);
  for (int64_t i = 0; i < n; ++i) {
    const double* pose = state->poses.data() + kPoseSize * i;
    if (!(builder.problem().HasParameterBlock(pose) && data.pose_fixed(i) == 0)) continue;
    covariance.GetCovarianceBlockInTangentSpace(pose, pose, block.data());
    double* out = result->covariance.data() + 36 * i;
    if (tangent == 6) {
      for (int k = 0; k < 36; ++k) out[k] = block[k];
    } else {
      // Rotation- or translation-only: place the 3×3 block at its place in [δt, δθ].
      const int offset = options.refine_mode == RefineMode::kRotation ? 3 : 0;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) out[(offset + r) * 6 + offset + c] = block[r * 3 + c];
    }
  }
  summary.covariance_ok = true;
}

// The W / Co association: one spatial index per term with a segment_class (enabled, with
// points), re-run after each Ceres run.
class Associator {
 public:
  Associator(const ProblemData& data, const SolverOptions& options, Summary* summary)
      : data_(data), options_(options) {
    for (int t = 0; t < NumTerms(); ++t) {
      const TermSpec& spec = Terms()[t];
      if (spec.segment_class <= 0 || !options.term(t).enabled) continue;
      if (data.I32(std::string(spec.points) + "_frame").rows == 0) continue;
      indices_.push_back(
          {t, std::make_unique<SegmentIndex>(data.F64("segments"), data.I32("segment_class"),
                                             data.F64("segment_z"), data.F64("segment_normal"),
                                             spec.segment_class, options.association_gate)});
      summary->association.push_back({spec.name, indices_.back().index->num_segments(), {}, {}});
    }
  }

  bool empty() const { return indices_.empty(); }

  // Associates every term's points under the current poses; records the statistics as the
  // initial or the final ones. Returns whether more than association_change_tolerance of the
  // points changed segment.
  bool Run(SolverState* state, bool initial, Summary* summary) const {
    int64_t changed = 0, points = 0;
    for (size_t slot = 0; slot < indices_.size(); ++slot) {
      const int t = indices_[slot].term;
      const std::string prefix = Terms()[t].points;
      AssociationStats stats;
      state->segment_of[t] = AssociatePoints(*indices_[slot].index, data_.I32(prefix + "_frame"),
                                             data_.F64(prefix + "_p_in_cam"), state->poses.data(),
                                             state->segment_of[t], &stats);
      (initial ? summary->association[slot].initial : summary->association[slot].final) = stats;
      changed += stats.num_changed;
      points += stats.num_points;
    }
    return changed > 0 && static_cast<double>(changed) >
                              options_.association_change_tolerance * static_cast<double>(points);
  }

 private:
  struct TermIndex {
    int term;
    std::unique_ptr<SegmentIndex> index;
  };
  const ProblemData& data_;
  const SolverOptions& options_;
  std::vector<TermIndex> indices_;
};

// The state the solver changes, from the input: poses (quaternions normalised), landmarks, and
// one association and FACaP plane slot per term.
SolverState InitialState(const ProblemData& data) {
  SolverState state;
  state.poses.assign(data.poses.data, data.poses.data + data.poses.rows * kPoseSize);
  NormalizeQuaternions(&state.poses);
  const ArrayRef<double> track_points = data.F64("track_points");
  if (track_points.rows > 0) {
    state.track_points.assign(track_points.data, track_points.data + track_points.rows * 3);
  }
  state.segment_of.resize(Terms().size());
  return state;
}

ceres::Solver::Options CeresOptions(const SolverOptions& options) {
  ceres::Solver::Options solver_options;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = options.function_tolerance;
  solver_options.gradient_tolerance = options.gradient_tolerance;
  solver_options.parameter_tolerance = options.parameter_tolerance;
  solver_options.num_threads = options.num_threads;
  solver_options.minimizer_progress_to_stdout = options.verbose;
  solver_options.logging_type = options.verbose ? ceres::PER_MINIMIZER_ITERATION : ceres::SILENT;
  return solver_options;
}

// The outer loop: Ceres, re-associate, rebuild when the association changed, until the
// association settles, outer_iterations runs, or max_time_s.
void RunOuterIterations(const SolverOptions& options, const Associator& associator,
                        const std::function<void()>& build, ProblemBuilder* builder,
                        SolverState* state, Summary* summary) {
  ceres::Solver::Options solver_options = CeresOptions(options);
  double remaining_time = options.max_time_s;
  // A round whose association is then re-run stops at round_function_tolerance; once the
  // association settles (or in the last round) Ceres runs to function_tolerance.
  bool settled = false;
  for (int round = 0; round < options.outer_iterations; ++round) {
    if (round > 0) build();
    const bool last = associator.empty() || settled || round + 1 == options.outer_iterations;
    solver_options.function_tolerance =
        last ? options.function_tolerance
             : std::max(options.function_tolerance, options.round_function_tolerance);
    solver_options.linear_solver_type = ChooseLinearSolver(options, builder->has_landmarks());
    solver_options.linear_solver_ordering =
        builder->has_landmarks() ? builder->ordering() : nullptr;
    solver_options.max_solver_time_in_seconds = std::max(remaining_time, 1e-3);
    ceres::Solver::Summary ceres_summary;
    if (builder->problem().NumResidualBlocks() > 0) {
      ceres::Solve(solver_options, &builder->problem(), &ceres_summary);
      if (options.verbose) std::cout << ceres_summary.FullReport() << "\n";
      summary->iterations += std::max(0, static_cast<int>(ceres_summary.iterations.size()) - 1);
      summary->ceres_time_s += ceres_summary.total_time_in_seconds;
      remaining_time -= ceres_summary.total_time_in_seconds;
      summary->termination = ceres::TerminationTypeToString(ceres_summary.termination_type);
      summary->message = ceres_summary.message;
      summary->linear_solver = ceres::LinearSolverTypeToString(solver_options.linear_solver_type);
      if (!ceres_summary.IsSolutionUsable()) {
        summary->success = false;
        ++summary->outer_iterations;
        return;
      }
    } else {
      summary->termination = "NO_RESIDUALS";
      summary->message = "no residual block: nothing to solve";
    }
    ++summary->outer_iterations;
    NormalizeQuaternions(&state->poses);
    if (associator.empty() || remaining_time <= 0) return;
    const bool changed = associator.Run(state, false, summary);
    const bool tight = solver_options.function_tolerance == options.function_tolerance;
    if (!changed && tight) return;
    settled = !changed;
  }
}

void MoveStateToResult(const ProblemData& data, const SolverOptions& options, SolverState* state,
                       SolveResult* result) {
  result->poses = std::move(state->poses);
  result->track_points = std::move(state->track_points);
  for (int t = 0; t < NumTerms(); ++t) {
    if (Terms()[t].segment_class > 0) result->segment_of[Terms()[t].key] = state->segment_of[t];
  }
  if (options.plane_mode == PlaneMode::kFacap) {
    for (int t = 0; t < NumTerms(); ++t) {
      if (!Terms()[t].facap_plane) continue;
      result->planes.insert(result->planes.end(), state->facap_planes.begin() + 4 * t,
                            state->facap_planes.begin() + 4 * t + 4);
      ++result->num_planes;
    }
  } else {
    const ArrayRef<double> planes = data.F64("planes");
    result->planes.assign(planes.data, planes.data + planes.rows * 4);
    result->num_planes = planes.rows;
  }
}

}  // namespace

SolveResult Solve(const ProblemData& data, const SolverOptions& options) {
  const auto start = Clock::now();
  ValidateProblem(data);
  options.Check();

  SolverState state = InitialState(data);
  SolveResult result;
  Summary& summary = result.summary;
  summary.num_poses = data.num_poses();
  for (int t = 0; t < NumTerms(); ++t) {
    summary.terms.push_back(TermSummary{});
    summary.terms.back().name = TermName(t);
    summary.terms.back().paper_weight = options.term(t).paper_weight;
  }

  ProblemBuilder builder(data, options, &state);
  if (options.plane_mode == PlaneMode::kFacap) builder.InitFacapPlanes();
  const Associator associator(data, options, &summary);
  associator.Run(&state, true, &summary);
  for (auto& a : summary.association) a.final = a.initial;
  // The association the current problem was built with: a problem built on the same association
  // is the same problem (the residual blocks point into state.poses), so it is not rebuilt.
  std::vector<std::vector<int>> built_with;
  const std::function<void()> build = [&]() {
    const auto build_start = Clock::now();
    // Between rounds only the association terms change: their blocks alone are rebuilt (false
    // before the first Build()).
    if (!builder.RebuildAssociationTerms()) builder.Build();
    built_with = state.segment_of;
    if (options.verbose) {
      std::cout << "bimcap: problem built in "
                << std::chrono::duration<double>(Clock::now() - build_start).count() << " s\n";
    }
  };
  build();

  // A non-finite initial cost (a pose at 1e300, a focal length of 1e-300, sigma = 1e-300 ...)
  // is a failed solve: Ceres would stop at once and report CONVERGENCE with the poses unchanged.
  // Every observation's residual and cost is finite where every term's sums are, so the search
  // for the first bad observation runs only where one is not.
  std::vector<TermCosts> initial_costs = EvaluateTerms(builder, options.num_threads);
  NonFinite initial_bad;
  for (const TermCosts& costs : initial_costs) {
    if (std::isfinite(costs.cost) && std::isfinite(costs.sq_sum)) continue;
    initial_bad = FindNonFinite(builder, state);
    break;
  }
  if (initial_bad.found()) {
    // Ceres' evaluation logs a page per non-finite block: mark the terms without evaluating.
    for (int t = 0; t < NumTerms(); ++t) {
      if (builder.terms()[t].active) initial_costs[t] = {kInf, kInf};
    }
    summary.success = false;
    summary.termination = "NON_FINITE_COST";
    summary.message = DescribeNonFinite(initial_bad, "initial");
    Record(initial_costs, builder, options, true, &summary);
    Record(initial_costs, builder, options, false, &summary);  // nothing moved
  } else {
    Record(initial_costs, builder, options, true, &summary);
    summary.success = true;
    RunOuterIterations(options, associator, build, &builder, &state, &summary);
    // Final costs on the final association.
    if (state.segment_of != built_with) build();
    Record(EvaluateTerms(builder, options.num_threads), builder, options, false, &summary);
    if (summary.success && !std::isfinite(summary.final_cost)) {
      const NonFinite final_bad = FindNonFinite(builder, state);
      summary.success = false;
      summary.termination = "NON_FINITE_COST";
      summary.message =
          final_bad.found() ? DescribeNonFinite(final_bad, "final") : "final cost is not finite";
    }
  }
  summary.num_free_poses = builder.num_free_poses();
  for (const TermSummary& t : summary.terms) {
    summary.num_residual_blocks += t.num_residual_blocks;
    summary.num_residuals += t.num_residuals;
  }
  if (options.compute_covariance && summary.success) {
    ComputeCovariance(builder, data, options, &state, &result);
  }
  MoveStateToResult(data, options, &state, &result);
  summary.time_s = std::chrono::duration<double>(Clock::now() - start).count();
  return result;
}

namespace {

std::string JsonNumber(double v) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}

std::string JsonString(const std::string& v) {
  std::string out = "\"";
  for (const char c : v) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

std::string JsonStats(const AssociationStats& s) {
  std::ostringstream o;
  o << "{\"num_points\": " << s.num_points << ", \"num_associated\": " << s.num_associated
    << ", \"num_rejected\": " << s.num_rejected << ", \"num_changed\": " << s.num_changed
    << ", \"mean_distance\": " << JsonNumber(s.mean_distance) << "}";
  return o.str();
}

}  // namespace

std::string SummaryToJson(const Summary& s) {
  std::ostringstream o;
  o << "{\n";
  o << "  \"success\": " << (s.success ? "true" : "false") << ",\n";
  o << "  \"termination\": " << JsonString(s.termination) << ",\n";
  o << "  \"message\": " << JsonString(s.message) << ",\n";
  o << "  \"linear_solver\": " << JsonString(s.linear_solver) << ",\n";
  o << "  \"iterations\": " << s.iterations << ",\n";
  o << "  \"outer_iterations\": " << s.outer_iterations << ",\n";
  o << "  \"time_s\": " << JsonNumber(s.time_s) << ",\n";
  o << "  \"ceres_time_s\": " << JsonNumber(s.ceres_time_s) << ",\n";
  o << "  \"initial_cost\": " << JsonNumber(s.initial_cost) << ",\n";
  o << "  \"final_cost\": " << JsonNumber(s.final_cost) << ",\n";
  o << "  \"initial_paper_objective\": " << JsonNumber(s.initial_paper_objective) << ",\n";
  o << "  \"final_paper_objective\": " << JsonNumber(s.final_paper_objective) << ",\n";
  o << "  \"num_poses\": " << s.num_poses << ",\n";
  o << "  \"num_free_poses\": " << s.num_free_poses << ",\n";
  o << "  \"num_residual_blocks\": " << s.num_residual_blocks << ",\n";
  o << "  \"num_residuals\": " << s.num_residuals << ",\n";
  o << "  \"terms\": [";
  for (size_t i = 0; i < s.terms.size(); ++i) {
    const TermSummary& t = s.terms[i];
    o << (i ? ",\n" : "\n") << "    {\"name\": " << JsonString(t.name)
      << ", \"active\": " << (t.active ? "true" : "false")
      << ", \"num_residual_blocks\": " << t.num_residual_blocks
      << ", \"num_residuals\": " << t.num_residuals << ", \"num_skipped\": " << t.num_skipped
      << ", \"sqrt_weight\": " << JsonNumber(t.sqrt_weight)
      << ", \"paper_weight\": " << JsonNumber(t.paper_weight)
      << ", \"initial_cost\": " << JsonNumber(t.initial_cost)
      << ", \"final_cost\": " << JsonNumber(t.final_cost)
      << ", \"initial_rms\": " << JsonNumber(t.initial_rms)
      << ", \"final_rms\": " << JsonNumber(t.final_rms)
      << ", \"initial_paper_objective\": " << JsonNumber(t.initial_paper_objective)
      << ", \"final_paper_objective\": " << JsonNumber(t.final_paper_objective) << "}";
  }
  o << "\n  ],\n";
  o << "  \"association\": [";
  for (size_t i = 0; i < s.association.size(); ++i) {
    const AssociationSummary& a = s.association[i];
    o << (i ? ",\n" : "\n") << "    {\"name\": " << JsonString(a.name)
      << ", \"num_segments\": " << a.num_segments << ", \"initial\": " << JsonStats(a.initial)
      << ", \"final\": " << JsonStats(a.final) << "}";
  }
  o << "\n  ],\n";
  o << "  \"covariance_requested\": " << (s.covariance_requested ? "true" : "false") << ",\n";
  o << "  \"covariance_ok\": " << (s.covariance_ok ? "true" : "false") << ",\n";
  o << "  \"covariance_message\": " << JsonString(s.covariance_message) << "\n";
  o << "}\n";
  return o.str();
}

}  // namespace bimcap
