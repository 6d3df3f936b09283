// How to solve: term switches, weighting, losses, association, Ceres settings. Validated by
// Check(); also read from / written to "key=value" text (the problem file and the binding use
// the same keys, listed by OptionKeys()).
#ifndef BIMCAP_OPTIONS_H_
#define BIMCAP_OPTIONS_H_

#include <map>
#include <string>
#include <vector>

#include "bimcap/pose.h"
#include "bimcap/problem.h"

namespace bimcap {

// The G term's residual: point consistency (m), two-frame reprojection (px), or landmark BA (px).
enum class GeometricMode { kPoint = 0, kReprojection = 1, kLandmark = 2 };
// kPaper: each term a mean with weight λ (paper_weight / N per squared residual), plain L2, the
// peers' objective. kRobust: residuals whitened by sigma, times `weight`, under a robust loss.
enum class Weighting { kPaper = 0, kRobust = 1 };
enum class LossType { kNone = 0, kHuber = 1, kCauchy = 2, kSoftL1 = 3, kArctan = 4, kTukey = 5 };
// kBim: floor/ceiling points against the fixed BIM planes. kFacap: one free plane per term.
enum class PlaneMode { kBim = 0, kFacap = 1 };
enum class LinearSolver {
  kAuto = 0,
  kDenseQr = 1,
  kDenseNormalCholesky = 2,
  kSparseNormalCholesky = 3,
  kDenseSchur = 4,
  kSparseSchur = 5,
  kIterativeSchur = 6,
};

struct TermOptions {
  bool enabled = true;
  double paper_weight = 1.0;  // λ of the peers' mean (kPaper; also used for the paper objective)
  double weight = 1.0;        // multiplier of the whitened squared residual (kRobust)
  double sigma = 0.05;        // noise scale in the residual's unit (kRobust)
  LossType loss = LossType::kHuber;
  double loss_scale = 1.0;    // in sigmas (the loss acts on the whitened residual)
};

// The terms, in summary order: the paper's (G with its depth prior, F, Ce, W, Co), then the pose
// prior and the odometry (not paper terms: never in PAPER weighting nor in the paper objective).
enum TermId {
  kTermG = 0,
  kTermDepth = 1,
  kTermF = 2,
  kTermCe = 3,
  kTermW = 4,
  kTermCo = 5,
  kTermPrior = 6,
  kTermOdometry = 7,
};
inline constexpr int kNumTerms = 8;
const char* TermName(int term);  // "G", "depth", "F", "Ce", "W", "Co", "prior", "odometry"

struct SolverOptions {
  GeometricMode geometric_mode = GeometricMode::kPoint;
  Weighting weighting = Weighting::kRobust;
  PlaneMode plane_mode = PlaneMode::kBim;
  RefineMode refine_mode = RefineMode::kFull;

  // G's sigma is used in kPoint mode (m); pixel_sigma in kReprojection / kLandmark (px).
  TermOptions geometric{true, 1.0, 1.0, 0.05, LossType::kHuber, 1.0};
  // Depth prior of landmarks (kLandmark only, observations with depth > 0).
  TermOptions depth{true, 1.0, 1.0, 0.05, LossType::kHuber, 1.0};
  TermOptions floor{true, 0.02, 1.0, 0.02, LossType::kHuber, 1.0};
  TermOptions ceiling{true, 0.02, 1.0, 0.02, LossType::kHuber, 1.0};
  TermOptions wall{true, 0.0007, 1.0, 0.05, LossType::kHuber, 1.0};
  TermOptions column{true, 0.0007, 1.0, 0.05, LossType::kHuber, 1.0};
  // Pose prior (kRobust only): each free pose held near its initial value, translation with
  // `prior.sigma` (m), rotation with `prior_sigma_r_deg` (degrees); plain L2 by default. Its
  // paper_weight must be 0 (it is not part of the peers' objective).
  TermOptions prior{true, 0.0, 1.0, 2.0, LossType::kNone, 1.0};
  double prior_sigma_r_deg = 20.0;
  // Odometry (kRobust only): consecutive free frames keep the input's relative motion, the
  // translation with `odometry.sigma` (m, in the earlier frame), the rotation with
  // `odometry_sigma_r_deg`; plain L2. Its paper_weight must be 0.
  TermOptions odometry{true, 0.0, 1.0, 0.3, LossType::kNone, 1.0};
  double odometry_sigma_r_deg = 15.0;
  double pixel_sigma = 1.0;

  // W / Co association: a point's nearest same-class segment within `association_gate` metres
  // (in xy) whose z range holds the point; re-associated after each Ceres run, at most
  // `outer_iterations` runs.
  double association_gate = 0.5;
  int outer_iterations = 5;
  // Stop re-associating once at most this fraction of the W / Co points changed segment.
  double association_change_tolerance = 1e-3;

  // Ceres.
  int max_iterations = 100;
  double function_tolerance = 1e-6;
  double gradient_tolerance = 1e-10;
  double parameter_tolerance = 1e-8;
  double max_time_s = 1e6;
  int num_threads = 2;
  LinearSolver linear_solver = LinearSolver::kAuto;
  bool compute_covariance = false;
  bool verbose = false;

  TermOptions& term(int id);
  const TermOptions& term(int id) const;

  // Throws OptionsError naming the option.
  void Check() const;
};

class OptionsError : public InputError {
 public:
  using InputError::InputError;
};

// Flat "key" → "value" form: e.g. "geometric_mode" → "POINT", "floor.enabled" → "1",
// "wall.paper_weight" → "0.0007". Unknown keys and unparsable values throw OptionsError.
std::map<std::string, std::string> OptionsToKeyValues(const SolverOptions& options);
SolverOptions OptionsFromKeyValues(const std::map<std::string, std::string>& values);
std::vector<std::string> OptionKeys();

// "key=value\n" lines (the problem file's `options` array).
std::string OptionsToText(const SolverOptions& options);
SolverOptions OptionsFromText(const std::string& text);

}  // namespace bimcap

#endif  // BIMCAP_OPTIONS_H_
