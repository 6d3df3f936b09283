// How to solve: term switches, weighting, losses, association, Ceres settings. Validated by
// Check(); also read from / written to "key=value" text (the problem file and the binding use
// the same keys, listed by OptionKeys()).
#ifndef BIMCAP_OPTIONS_H_
#define BIMCAP_OPTIONS_H_

#include <map>
#include <string>
#include <string_view>
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
  double loss_scale = 1.0;  // in sigmas (the loss acts on the whitened residual)
  // The term's own scalars (TermSpec::params), by name, e.g. "sigma_r_deg" of the pose prior.
  std::map<std::string, double, std::less<>> params;

  double param(std::string_view name) const;  // throws OptionsError when the term has none
};

struct SolverOptions {
  GeometricMode geometric_mode = GeometricMode::kPoint;
  Weighting weighting = Weighting::kRobust;
  PlaneMode plane_mode = PlaneMode::kBim;
  RefineMode refine_mode = RefineMode::kFull;

  // One TermOptions per term of the registry (terms.h), in its order, starting from each
  // term's defaults. G's sigma is used in kPoint mode (m); pixel_sigma in kReprojection /
  // kLandmark (px).
  std::vector<TermOptions> terms;
  double pixel_sigma = 1.0;

  // W / Co association: a point's nearest same-class segment within `association_gate` metres
  // (in xy) whose z range holds the point; re-associated after each Ceres run, at most
  // `outer_iterations` runs.
  double association_gate = 0.5;
  int outer_iterations = 5;
  // Stop re-associating once at most this fraction of the W / Co points changed segment.
  double association_change_tolerance = 1e-3;
  // W / Co: Ceres' function_tolerance in a round whose poses only seed the next association
  // (not below function_tolerance). Once the association settles, or in the last round, Ceres
  // runs to function_tolerance on it: the rounds before stop at a coarser one, and the solve
  // leaves out the slow tail of each (at 1000 frames, 18 iterations in 3 rounds became 12 in
  // 4, the same poses). 0: function_tolerance in every round.
  double round_function_tolerance = 1e-4;

  // Ceres.
  int max_iterations = 100;
  double function_tolerance = 1e-6;
  double gradient_tolerance = 1e-10;
  double parameter_tolerance = 1e-8;
  double max_time_s = 1e6;
  int num_threads = 2;
  // At most this many observations of a term that share their parameter blocks (a frame's
  // floor points, the matches of a frame pair) go into one Ceres residual block, the term's loss
  // applied to each (cost_functions/batched.h): the same cost and gradient, a fraction of
  // Ceres' per-block work. A compressed batch is 7 or 13 rows however many observations it has,
  // so fewer, larger batches leave Ceres fewer rows (docs/speed.md: 64 → 1024 made the real
  // 1000-frame problem 1.4× faster). 1: one residual block per observation, with Ceres' loss.
  int batch_size = 1024;
  // A batch of more residuals than its parameter blocks' tangent size goes to Ceres as that many
  // rows plus one, built from its Gauss-Newton matrix and gradient (cost_functions/batched.h: the
  // same cost, gradient and Gauss-Newton matrix to rounding); false: one row per residual.
  bool compress_batches = true;
  LinearSolver linear_solver = LinearSolver::kAuto;
  bool compute_covariance = false;
  bool verbose = false;

  SolverOptions();  // every term at its registry defaults

  // A named starting point (throws OptionsError naming "preset" for an unknown name):
  //  "robust": what `bimcap refine` uses for BIMCaP. ROBUST weighting; G as the reprojection
  //      error (pixel_sigma 2 px, each error whitened by its keypoint depth's noise, depth.sigma
  //      2 cm); floor and ceiling sigma 5 cm; a Cauchy loss on each of the paper's terms
  //      (completed depth and estimated labels have heavy-tailed errors).
  //  "paper": the peers' objective. PAPER weighting (each term λ · the mean of its squared
  //      residuals, plain L2); G as FACaP's point error (m). The sigmas and losses are robust's:
  //      the solve does not use them, the diagnostics (observability) do.
  static SolverOptions Preset(std::string_view name);
  static std::vector<std::string> PresetNames();

  TermOptions& term(int id) { return terms.at(static_cast<size_t>(id)); }
  const TermOptions& term(int id) const { return terms.at(static_cast<size_t>(id)); }
  // By key ("floor") or name ("F"); throws OptionsError for an unknown term.
  TermOptions& term(std::string_view key_or_name);
  const TermOptions& term(std::string_view key_or_name) const;

  // Throws OptionsError naming the option.
  void Check() const;
};

class OptionsError : public InputError {
 public:
  using InputError::InputError;
};

// Flat "key" → "value" form: e.g. "geometric_mode" → "POINT", "floor.enabled" → "1",
// "wall.paper_weight" → "0.0007", "prior.sigma_r_deg" → "20". Unknown keys and unparsable values
// throw OptionsError. Keys renamed since files were written are still read (kRenamedKeys).
std::map<std::string, std::string> OptionsToKeyValues(const SolverOptions& options);
SolverOptions OptionsFromKeyValues(const std::map<std::string, std::string>& values);
std::vector<std::string> OptionKeys();

// What an option is, for the binding and `--print-config`: its key, kind ("enum", "bool", "int",
// "float"), default value as text, and the allowed values of an enum.
struct OptionSpec {
  std::string key;
  std::string kind;
  std::string default_value;
  std::vector<std::string> choices;
};
std::vector<OptionSpec> OptionSpecs();

// "key=value\n" lines (the problem file's `options` array).
std::string OptionsToText(const SolverOptions& options);
SolverOptions OptionsFromText(const std::string& text);

}  // namespace bimcap

#endif  // BIMCAP_OPTIONS_H_
