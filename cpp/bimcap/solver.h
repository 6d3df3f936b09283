// Solve: validate → associate → build → Ceres → re-associate ... → summary (and covariance).
#ifndef BIMCAP_SOLVER_H_
#define BIMCAP_SOLVER_H_

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "bimcap/association.h"
#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap {

struct TermSummary {
  std::string name;  // TermSpec::name: "G", "depth", "F", "Ce", "W", "Co", "prior" ...
  bool active = false;
  int64_t num_residual_blocks = 0;  // observations in the final problem
  int64_t num_residuals = 0;        // scalar residuals (blocks × residual size)
  int64_t num_skipped = 0;
  double sqrt_weight = 0.0;   // the functors' scalar s
  double paper_weight = 0.0;  // λ
  // Ceres cost of the term (½ Σ ρ(‖s r‖²)) before the first and after the last run.
  double initial_cost = 0.0;
  double final_cost = 0.0;
  // Root mean square of the raw (unweighted) residuals, in the term's unit (m or px; the
  // prior's residuals are whitened: in sigmas).
  double initial_rms = 0.0;
  double final_rms = 0.0;
  // λ · mean ‖r‖² over the observations: this term's share of the peers' objective.
  double initial_paper_objective = 0.0;
  double final_paper_objective = 0.0;
};

struct AssociationSummary {
  std::string name;  // "W" / "Co"
  int64_t num_segments = 0;
  AssociationStats initial;
  AssociationStats final;
};

struct Summary {
  bool success = false;
  std::string termination;  // the last Ceres run's termination type, or NON_FINITE_COST /
                            // NO_RESIDUALS
  std::string message;      // the last Ceres run's message
  std::string linear_solver;
  int iterations = 0;         // Ceres iterations over all outer rounds
  int outer_iterations = 0;   // Ceres runs
  double time_s = 0.0;        // wall time of Solve()
  double ceres_time_s = 0.0;  // time inside ceres::Solve
  double initial_cost = 0.0;  // Ceres cost, all terms
  double final_cost = 0.0;
  // Σ over terms of λ · mean ‖r‖² (the peers' objective, whatever the weighting mode).
  double initial_paper_objective = 0.0;
  double final_paper_objective = 0.0;
  int64_t num_poses = 0;
  int64_t num_free_poses = 0;
  int64_t num_residual_blocks = 0;
  int64_t num_residuals = 0;
  std::vector<TermSummary> terms;
  std::vector<AssociationSummary> association;
  bool covariance_requested = false;
  bool covariance_ok = false;
  std::string covariance_message;
};

struct SolveResult {
  std::vector<double> poses;         // (N, 7) refined world_from_cam, TUM order, unit quaternions
  std::vector<double> planes;        // BIM mode: the input planes (Q, 4); FACaP: (2, 4) floor,
  int64_t num_planes = 0;            //   ceiling fitted planes (NaN row when not estimated)
  std::vector<double> track_points;  // (P, 3) refined landmarks
  // Per segment term (its key: "wall", "column"), each point's final segment (-1 = none).
  std::map<std::string, std::vector<int>> segment_of;
  // (N, 6, 6) covariance of each pose in its tangent space [δt, δθ] (zeros for fixed or absent
  // poses); empty unless requested and computed.
  std::vector<double> covariance;
  Summary summary;
};

// Solves one problem. Throws ProblemError / OptionsError on invalid input (nothing is aborted);
// a Ceres failure is reported in `summary.success` / `termination`, not thrown. A non-finite
// initial or final cost is a failure too: success = false, termination "NON_FINITE_COST", and the
// message names the term, the first non-finite residual block and the frames it depends on (the
// solve does not start when the initial cost is not finite; the poses come back unchanged).
SolveResult Solve(const ProblemData& problem, const SolverOptions& options);

// The summary as a JSON object (NaN / Inf as null).
std::string SummaryToJson(const Summary& summary);

}  // namespace bimcap

#endif  // BIMCAP_SOLVER_H_
