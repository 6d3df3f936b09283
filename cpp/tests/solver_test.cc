// Drift → solve → recover, per term alone and all together; the paper-mode objective equals the
// peers' formula evaluated directly; gauge, refine modes, covariance, input errors.
#include "bimcap/solver.h"

#include <ceres/crs_matrix.h>
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "bimcap/builder.h"
#include "bimcap/cost_functions/point_to_segment.h"
#include "bimcap/terms.h"
#include "test_problems.h"

namespace bimcap {
namespace {

using testing::MakeTestProblem;
using testing::OwnedProblem;
using testing::PoseErrors;

SolverOptions OnlyTerms(std::initializer_list<int> terms) {
  SolverOptions o;
  for (int t = 0; t < NumTerms(); ++t) o.term(t).enabled = false;
  for (int t : terms) o.term(t).enabled = true;
  return o;
}

Eigen::Vector3d Translation(const std::vector<double>& poses, int i) {
  return Eigen::Vector3d(poses[7 * i], poses[7 * i + 1], poses[7 * i + 2]);
}
Eigen::Quaterniond Rotation(const std::vector<double>& poses, int i) {
  return Eigen::Quaterniond(poses[7 * i + 6], poses[7 * i + 3], poses[7 * i + 4], poses[7 * i + 5]);
}

// RMS errors of the parts a term observes: z and tilt (F / Ce), xy and yaw (W / Co).
void PartialErrors(const std::vector<double>& est, const std::vector<double>& gt, double* z,
                   double* tilt_deg, double* xy, double* yaw_deg) {
  const int n = static_cast<int>(gt.size() / 7);
  double sz = 0, st = 0, sxy = 0, syaw = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d d = Translation(est, i) - Translation(gt, i);
    sz += d.z() * d.z();
    sxy += d.head<2>().squaredNorm();
    const Eigen::Matrix3d e = (Rotation(est, i) * Rotation(gt, i).conjugate()).toRotationMatrix();
    const double tilt =
        std::acos(std::clamp(e(2, 2), -1.0, 1.0)) * 180 / M_PI;  // where world z goes
    const double yaw = std::atan2(e(1, 0), e(0, 0)) * 180 / M_PI;
    st += tilt * tilt;
    syaw += yaw * yaw;
  }
  *z = std::sqrt(sz / n);
  *tilt_deg = std::sqrt(st / n);
  *xy = std::sqrt(sxy / n);
  *yaw_deg = std::sqrt(syaw / n);
}

// Largest change between two pose sets of what F does not observe: xy (m) and the rotation about
// the world z (degrees; the z part of the rotation vector of R_a R_bᵀ, free of the tilt coupling
// of an Euler-angle yaw).
void MaxPlanChange(const std::vector<double>& a, const std::vector<double>& b, double* xy,
                   double* yaw_deg) {
  *xy = 0;
  *yaw_deg = 0;
  for (size_t i = 0; i < a.size() / 7; ++i) {
    *xy = std::max(*xy, (Translation(a, i) - Translation(b, i)).head<2>().norm());
    const Eigen::AngleAxisd e(Rotation(a, i) * Rotation(b, i).conjugate());
    *yaw_deg = std::max(*yaw_deg, std::abs(e.angle() * e.axis().z()) * 180 / M_PI);
  }
}

class SolverTest : public ::testing::Test {
 protected:
  void SetUp() override {
    problem = MakeTestProblem();
    PoseErrors(problem.poses, problem.gt_poses, &init_t, &init_r);
    ASSERT_GT(init_t, 0.05);
    ASSERT_GT(init_r, 0.5);
  }
  OwnedProblem problem;
  double init_t = 0, init_r = 0;
};

TEST_F(SolverTest, AllTermsRecoverTheTruth) {
  const SolveResult r = Solve(problem.View(), SolverOptions());
  ASSERT_TRUE(r.summary.success) << r.summary.message;
  double t, rot;
  PoseErrors(r.poses, problem.gt_poses, &t, &rot);
  EXPECT_LT(t, 0.01) << "from " << init_t;
  EXPECT_LT(rot, 0.1) << "from " << init_r;
  EXPECT_LT(r.summary.final_cost, r.summary.initial_cost);
  EXPECT_GE(r.summary.outer_iterations, 1);
  ASSERT_EQ(r.summary.association.size(), 2u);
  EXPECT_EQ(r.summary.association[0].final.num_rejected, 0);
  // The pose prior is on by default (ROBUST), one block per free pose, outside the paper objective.
  const TermSummary& prior = r.summary.terms[TermIndex("prior")];
  EXPECT_EQ(prior.name, "prior");
  EXPECT_TRUE(prior.active);
  EXPECT_EQ(prior.num_residual_blocks, static_cast<int64_t>(problem.poses.size() / 7 - 1));
  EXPECT_GT(prior.final_cost, 0.0);
  EXPECT_EQ(prior.final_paper_objective, 0.0);
  // Fixed frame 0 did not move.
  for (int k = 0; k < 7; ++k) EXPECT_EQ(r.poses[k], problem.poses[k]);
}

TEST_F(SolverTest, GeometricAloneRecoversRelativeMotion) {
  for (GeometricMode mode :
       {GeometricMode::kPoint, GeometricMode::kReprojection, GeometricMode::kLandmark}) {
    SolverOptions o = OnlyTerms({TermIndex("G"), TermIndex("depth")});
    o.geometric_mode = mode;
    const SolveResult r = Solve(problem.View(), o);
    ASSERT_TRUE(r.summary.success);
    double t, rot;
    PoseErrors(r.poses, problem.gt_poses, &t, &rot);
    // Frame 0 is fixed at the truth, so chaining the matches recovers the rest up to noise drift.
    EXPECT_LT(t, 0.03) << static_cast<int>(mode);
    EXPECT_LT(rot, 0.5) << static_cast<int>(mode);
  }
}

TEST_F(SolverTest, FloorAloneFixesHeightAndTilt) {
  for (int term : {TermIndex("F"), TermIndex("Ce")}) {
    const SolveResult r = Solve(problem.View(), OnlyTerms({term}));
    double z0, tilt0, xy0, yaw0, z, tilt, xy, yaw;
    PartialErrors(problem.poses, problem.gt_poses, &z0, &tilt0, &xy0, &yaw0);
    PartialErrors(r.poses, problem.gt_poses, &z, &tilt, &xy, &yaw);
    EXPECT_LT(z, 0.02) << TermName(term) << " from " << z0;
    EXPECT_LT(z, 0.5 * z0) << TermName(term);
    EXPECT_LT(tilt, 0.3) << TermName(term);
  }
}

// A term's arrays may be left out (the binding's and the problem file's promise): a problem with
// the core arrays and the F and W arrays only is valid, and F + W alone solve it as they do when
// every other term is present but disabled.
TEST_F(SolverTest, ATermsArraysMayBeLeftOut) {
  const ProblemData full = problem.View();
  ProblemData part;
  for (const char* name : {"poses", "timestamps", "pose_fixed", "cameras", "frame_camera",
                           "floor_frame", "floor_p_in_cam", "floor_plane", "planes", "wall_frame",
                           "wall_p_in_cam", "segments", "segment_class", "segment_z"}) {
    const FieldSpec* spec = FindField(name);
    ASSERT_NE(spec, nullptr) << name;
    if (spec->dtype == DType::kFloat64) {
      part.Set(name, full.F64(name));
    } else {
      part.Set(name, full.I32(name));
    }
  }
  EXPECT_TRUE(part.F64("ceiling_p_in_cam").empty());
  ValidateProblem(part);
  SolverOptions only = OnlyTerms({TermIndex("F"), TermIndex("W")});
  only.num_threads = 1;  // bit-for-bit comparable
  const SolveResult r = Solve(part, only);
  ASSERT_TRUE(r.summary.success) << r.summary.message;
  EXPECT_EQ(r.poses, Solve(full, only).poses);
  // Every term enabled: the absent ones are empty, not an error.
  EXPECT_TRUE(Solve(part, SolverOptions()).summary.success);
}

TEST_F(SolverTest, WallAloneFixesPlanPositionAndYaw) {
  const SolveResult r = Solve(problem.View(), OnlyTerms({TermIndex("W")}));
  double z, tilt, xy0, yaw0, xy, yaw;
  PartialErrors(problem.poses, problem.gt_poses, &z, &tilt, &xy0, &yaw0);
  PartialErrors(r.poses, problem.gt_poses, &z, &tilt, &xy, &yaw);
  EXPECT_LT(xy, 0.02) << "from " << xy0;
  EXPECT_LT(yaw, 0.3) << "from " << yaw0;
  EXPECT_GE(r.summary.outer_iterations, 1);
}

TEST_F(SolverTest, ColumnAloneReducesItsResiduals) {
  const SolveResult r = Solve(problem.View(), OnlyTerms({TermIndex("Co")}));
  const TermSummary& co = r.summary.terms[TermIndex("Co")];
  ASSERT_TRUE(co.active);
  EXPECT_LT(co.final_rms, 0.5 * co.initial_rms);
  EXPECT_LT(co.final_rms, 0.02);
}

// Σ over terms of λ · mean ‖r‖², computed here from the refined poses without the functors.
double PaperObjective(const OwnedProblem& p, const std::vector<double>& poses,
                      const SolveResult& r) {
  auto world = [&](int frame, const double* c) {
    return Eigen::Vector3d(Rotation(poses, frame) * Eigen::Vector3d(c[0], c[1], c[2]) +
                           Translation(poses, frame));
  };
  double g = 0;
  const double* k = p.cameras.data();
  const size_t m = p.match_frames.size() / 2;
  for (size_t i = 0; i < m; ++i) {
    const double* uv = &p.match_uv[4 * i];
    const double da = p.match_depth[2 * i], db = p.match_depth[2 * i + 1];
    const double ca[3] = {(uv[0] - k[2]) / k[0] * da, (uv[1] - k[3]) / k[1] * da, da};
    const double cb[3] = {(uv[2] - k[2]) / k[0] * db, (uv[3] - k[3]) / k[1] * db, db};
    g += (world(p.match_frames[2 * i], ca) - world(p.match_frames[2 * i + 1], cb)).squaredNorm();
  }
  double f = 0;
  for (size_t i = 0; i < p.floor_frame.size(); ++i) {
    const double* pl = &p.planes[4 * p.floor_plane[i]];
    const double d = Eigen::Vector3d(pl[0], pl[1], pl[2])
                         .dot(world(p.floor_frame[i], &p.floor_p_in_cam[3 * i])) +
                     pl[3];
    f += d * d;
  }
  double ce = 0;
  for (size_t i = 0; i < p.ceiling_frame.size(); ++i) {
    const double* pl = &p.planes[4 * p.ceiling_plane[i]];
    const double d = Eigen::Vector3d(pl[0], pl[1], pl[2])
                         .dot(world(p.ceiling_frame[i], &p.ceiling_p_in_cam[3 * i])) +
                     pl[3];
    ce += d * d;
  }
  double w = 0;
  int nw = 0;
  for (size_t i = 0; i < p.wall_frame.size(); ++i) {
    const int s = r.segment_of.at("wall")[i];
    if (s < 0) continue;
    const Eigen::Vector3d q = world(p.wall_frame[i], &p.wall_p_in_cam[3 * i]);
    const double* seg = &p.segments[4 * s];
    const double d =
        PointToSegmentDistance2D(q.x(), q.y(), Eigen::Vector4d(seg[0], seg[1], seg[2], seg[3]));
    w += d * d;
    ++nw;
  }
  return 1.0 * g / m + 0.02 * f / p.floor_frame.size() + 0.02 * ce / p.ceiling_frame.size() +
         0.0007 * w / nw;
}

TEST_F(SolverTest, PaperObjectiveEqualsThePeersFormula) {
  // The prior is switched on and must still stay out: PAPER weighting is exactly the peers'.
  SolverOptions o = OnlyTerms(
      {TermIndex("G"), TermIndex("F"), TermIndex("Ce"), TermIndex("W"), TermIndex("prior")});
  o.weighting = Weighting::kPaper;
  const SolveResult r = Solve(problem.View(), o);
  ASSERT_TRUE(r.summary.success);
  EXPECT_FALSE(r.summary.terms[TermIndex("prior")].active);
  EXPECT_EQ(r.summary.terms[TermIndex("prior")].num_residual_blocks, 0);
  const double direct_final = PaperObjective(problem, r.poses, r);
  EXPECT_NEAR(r.summary.final_paper_objective, direct_final, 1e-9 * direct_final);
  // Ceres minimises ½ Σ ‖s r‖² with s² = λ / N: its cost is half the paper's objective.
  EXPECT_NEAR(r.summary.final_cost, 0.5 * direct_final, 1e-9 * direct_final);
  EXPECT_LT(r.summary.final_paper_objective, r.summary.initial_paper_objective);
  // Hand check of the per-term weights: s = sqrt(λ / N).
  EXPECT_NEAR(r.summary.terms[TermIndex("F")].sqrt_weight,
              std::sqrt(0.02 / problem.floor_frame.size()), 1e-15);
}

TEST_F(SolverTest, PriorHoldsWhatTheFloorDoesNotSee) {
  // F alone observes z, roll and pitch; x, y and yaw are left to the prior, which holds them at
  // their initial values while F still fixes the height.
  const SolveResult r = Solve(problem.View(), OnlyTerms({TermIndex("F"), TermIndex("prior")}));
  ASSERT_TRUE(r.summary.success) << r.summary.message;
  double xy, yaw;
  MaxPlanChange(r.poses, problem.poses, &xy, &yaw);
  std::printf("F + prior: max xy change %.3g m, max yaw change %.3g deg\n", xy, yaw);
  EXPECT_LT(xy, 0.01);
  EXPECT_LT(yaw, 0.1);
  double z0, tilt0, xy0, yaw0, z, tilt, xy1, yaw1;
  PartialErrors(problem.poses, problem.gt_poses, &z0, &tilt0, &xy0, &yaw0);
  PartialErrors(r.poses, problem.gt_poses, &z, &tilt, &xy1, &yaw1);
  EXPECT_LT(z, 0.02) << "from " << z0;
  EXPECT_LT(tilt, 0.3) << "from " << tilt0;
  const TermSummary& prior = r.summary.terms[TermIndex("prior")];
  ASSERT_TRUE(prior.active);
  EXPECT_EQ(prior.num_residuals, 6 * prior.num_residual_blocks);
  // Negative control: without the prior and with one Ceres row per residual (ambient Jacobians
  // times Ceres' Plus Jacobian), LM leaks steps into the unobserved yaw (the numerical noise of
  // its zero gradient over a vanishing damping; 0.7° here, 14° on the Python synthetic problem).
  // x and y do not move: their Jacobian columns are exactly zero for a level floor.
  SolverOptions rows = OnlyTerms({TermIndex("F")});
  rows.compress_batches = false;
  const SolveResult bare = Solve(problem.View(), rows);
  ASSERT_TRUE(bare.summary.success);
  EXPECT_FALSE(bare.summary.terms[TermIndex("prior")].active);
  MaxPlanChange(bare.poses, problem.poses, &xy, &yaw);
  std::printf("F alone, rows: max xy change %.3g m, max yaw change %.3g deg\n", xy, yaw);
  EXPECT_GT(yaw, 0.1);
  // The compressed batches take F's Jacobian in the tangent space, where a level floor's yaw
  // column, s (n × R p)_z, is exactly zero: with more than 6 floor points in every frame (so
  // every batch compressed) yaw stays put without the prior too.
  const SolveResult compressed = Solve(problem.View(), OnlyTerms({TermIndex("F")}));
  ASSERT_TRUE(compressed.summary.success);
  MaxPlanChange(compressed.poses, problem.poses, &xy, &yaw);
  std::printf("F alone, compressed: max xy change %.3g m, max yaw change %.3g deg\n", xy, yaw);
  EXPECT_LT(xy, 1e-9);
  EXPECT_LT(yaw, 0.01);
}

TEST_F(SolverTest, RefineModesHoldTheirPart) {
  SolverOptions o;
  o.refine_mode = RefineMode::kRotation;
  SolveResult r = Solve(problem.View(), o);
  for (size_t i = 0; i < problem.poses.size() / 7; ++i)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(r.poses[7 * i + k], problem.poses[7 * i + k]);
  o.refine_mode = RefineMode::kTranslation;
  r = Solve(problem.View(), o);
  for (size_t i = 0; i < problem.poses.size() / 7; ++i)
    for (int k = 3; k < 7; ++k) EXPECT_NEAR(r.poses[7 * i + k], problem.poses[7 * i + k], 1e-12);
}

TEST_F(SolverTest, FacapPlanesAreFittedAndRefined) {
  SolverOptions o = OnlyTerms({TermIndex("G"), TermIndex("F"), TermIndex("Ce")});
  o.plane_mode = PlaneMode::kFacap;
  const SolveResult r = Solve(problem.View(), o);
  ASSERT_TRUE(r.summary.success);
  ASSERT_EQ(r.num_planes, 2);
  EXPECT_NEAR(Eigen::Vector3d(r.planes[0], r.planes[1], r.planes[2]).norm(), 1.0, 1e-9);
  EXPECT_GT(r.planes[2], 0.99);  // the floor is horizontal after refinement
  EXPECT_LT(r.summary.terms[TermIndex("F")].final_rms, 0.02);
}

TEST_F(SolverTest, CovarianceIsSymmetricPositive) {
  SolverOptions o;
  o.compute_covariance = true;
  const SolveResult r = Solve(problem.View(), o);
  ASSERT_TRUE(r.summary.covariance_ok) << r.summary.covariance_message;
  ASSERT_EQ(r.covariance.size(), problem.poses.size() / 7 * 36);
  for (int k = 0; k < 36; ++k) EXPECT_EQ(r.covariance[k], 0.0);  // frame 0 is fixed
  const Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> c(r.covariance.data() +
                                                                         36 * 5);
  EXPECT_NEAR((c - c.transpose()).norm(), 0.0, 1e-12);
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(c);
  EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
}

TEST_F(SolverTest, InvalidInputThrowsNamingTheField) {
  OwnedProblem p = problem;
  p.floor_plane[3] = 5;
  try {
    Solve(p.View(), SolverOptions());
    FAIL();
  } catch (const ProblemError& e) {
    EXPECT_EQ(e.field(), "floor_plane");
  }
  SolverOptions o;
  o.association_gate = -1;
  EXPECT_THROW(Solve(problem.View(), o), OptionsError);
}

// A value that overflows a residual (a pose at 1e300, a focal length of 1e-300, sigma = 1e-300)
// makes the initial cost non-finite: a failure naming the term and the frame, poses unchanged.
TEST_F(SolverTest, NonFiniteInitialCostIsAFailureNamingTheTermAndFrame) {
  struct Case {
    const char* name;
    const char* term;
    const char* frame;  // expected in the message, or null
  };
  for (const Case& c :
       {Case{"pose", "G (geometric)", "4"}, Case{"focal", "G (geometric)", nullptr},
        Case{"sigma", "W (wall)", nullptr}, Case{"floor point", "F (floor)", nullptr}}) {
    SCOPED_TRACE(c.name);
    OwnedProblem p = problem;
    SolverOptions o;
    const std::string name = c.name;
    if (name == "pose") {
      p.poses[7 * 4 + 0] = 1e300;
    } else if (name == "focal") {
      p.cameras[0] = 1e-300;
    } else if (name == "sigma") {
      o.term("wall").sigma = 1e-300;
    } else {
      p.floor_p_in_cam[3 * p.floor_frame.size() / 2] = 1e308;
      o.term("geometric").enabled = o.term("wall").enabled = o.term("column").enabled = false;
    }
    const SolveResult r = Solve(p.View(), o);
    EXPECT_FALSE(r.summary.success);
    EXPECT_EQ(r.summary.termination, "NON_FINITE_COST");
    EXPECT_EQ(r.summary.iterations, 0);
    EXPECT_NE(r.summary.message.find("initial cost is not finite"), std::string::npos)
        << r.summary.message;
    EXPECT_NE(r.summary.message.find(c.term), std::string::npos) << r.summary.message;
    if (c.frame != nullptr) {  // "(frames 3, 4)" or "(frame 4)"
      const std::string m = r.summary.message;
      const size_t open = m.find("(frame");
      ASSERT_NE(open, std::string::npos) << m;
      EXPECT_NE(m.substr(open, m.find(')', open) - open).find(c.frame), std::string::npos) << m;
    }
    EXPECT_FALSE(std::isfinite(r.summary.initial_cost));
    for (size_t k = 0; k < p.poses.size(); ++k) {
      if (k % 7 >= 3) continue;  // the quaternions come back normalised
      EXPECT_EQ(r.poses[k], p.poses[k]);
    }
    EXPECT_NE(SummaryToJson(r.summary).find("\"success\": false"), std::string::npos);
  }
}

TEST_F(SolverTest, FiniteProblemsStillSucceed) {
  const SolveResult r = Solve(problem.View(), SolverOptions());
  EXPECT_TRUE(r.summary.success) << r.summary.message;
  EXPECT_NE(r.summary.termination, "NON_FINITE_COST");
  EXPECT_TRUE(std::isfinite(r.summary.final_cost));
}

}  // namespace
}  // namespace bimcap

namespace bimcap {
namespace {

// Cost, gradient and JᵀJ (tangent space, dense) of a builder's problem at the state's poses.
struct Evaluated {
  double cost = 0.0;
  std::vector<double> gradient;
  Eigen::MatrixXd jtj;
};

Evaluated EvaluateProblem(ProblemBuilder* builder) {
  Evaluated e;
  ceres::CRSMatrix jacobian;
  EXPECT_TRUE(builder->problem().Evaluate(ceres::Problem::EvaluateOptions(), &e.cost, nullptr,
                                          &e.gradient, &jacobian));
  e.jtj = testing::DenseJtJ(jacobian);
  return e;
}

// Every wall / column point on a segment of its class, the k-th such segment by `shift` (not the
// right one: any valid association is a problem to build); a fifth of them, and the points of
// `skip_frame`, on none.
void Associate(const OwnedProblem& problem, int shift, SolverState* state, int skip_frame = -1) {
  for (const char* key : {"W", "Co"}) {
    const int t = TermIndex(key);
    const std::vector<int32_t>& frames =
        t == TermIndex("W") ? problem.wall_frame : problem.column_frame;
    std::vector<int> of_class;
    for (size_t s = 0; s < problem.segment_class.size(); ++s) {
      if (problem.segment_class[s] == Terms()[t].segment_class)
        of_class.push_back(static_cast<int>(s));
    }
    ASSERT_FALSE(of_class.empty());
    state->segment_of[t].assign(frames.size(), -1);
    for (size_t i = 0; i < frames.size(); ++i) {
      if ((i + shift) % 5 == 0 || frames[i] == skip_frame) continue;
      state->segment_of[t][i] = of_class[(i + shift) % of_class.size()];
    }
  }
}

// refine's options with only these terms.
SolverOptions RobustOnly(std::initializer_list<int> terms) {
  SolverOptions o = SolverOptions::Preset("robust");
  for (int t = 0; t < NumTerms(); ++t) o.term(t).enabled = false;
  for (int t : terms) o.term(t).enabled = true;
  return o;
}

SolverState StateOf(const OwnedProblem& problem) {
  SolverState state;
  state.poses = problem.poses;
  return state;
}

TEST(BuilderTest, RebuildAssociationTermsGivesTheProblemBuildGives) {
  const OwnedProblem problem = MakeTestProblem();
  const ProblemData data = problem.View();
  const SolverOptions options = SolverOptions::Preset("robust");
  SolverState state = StateOf(problem);
  ProblemBuilder builder(data, options, &state);
  Associate(problem, 0, &state);
  builder.Build();
  const int64_t free_poses = builder.num_free_poses();
  Associate(problem, 3, &state);
  ASSERT_TRUE(builder.RebuildAssociationTerms());

  SolverState fresh_state = StateOf(problem);
  ProblemBuilder fresh(data, options, &fresh_state);
  Associate(problem, 3, &fresh_state);
  fresh.Build();

  EXPECT_EQ(builder.num_free_poses(), free_poses);
  EXPECT_EQ(fresh.num_free_poses(), free_poses);
  for (int t = 0; t < NumTerms(); ++t) {
    EXPECT_EQ(builder.terms()[t].num_residual_blocks, fresh.terms()[t].num_residual_blocks) << t;
    EXPECT_EQ(builder.terms()[t].num_skipped, fresh.terms()[t].num_skipped) << t;
    EXPECT_EQ(builder.terms()[t].ids.size(), fresh.terms()[t].ids.size()) << t;
  }
  EXPECT_GT(builder.terms()[TermIndex("W")].num_residual_blocks, 0);
  const Evaluated a = EvaluateProblem(&builder), b = EvaluateProblem(&fresh);
  EXPECT_NEAR(a.cost, b.cost, 1e-12 * b.cost);
  ASSERT_EQ(a.gradient.size(), b.gradient.size());
  double g_max = 0.0;
  for (double v : b.gradient) g_max = std::max(g_max, std::abs(v));
  for (size_t k = 0; k < a.gradient.size(); ++k) {
    EXPECT_NEAR(a.gradient[k], b.gradient[k], 1e-12 * g_max) << k;
  }
  EXPECT_LE((a.jtj - b.jtj).cwiseAbs().maxCoeff(), 1e-12 * b.jtj.cwiseAbs().maxCoeff());
  // The association before gives another problem (the test can tell them apart).
  Associate(problem, 0, &fresh_state);
  fresh.Build();
  EXPECT_GT(std::abs(EvaluateProblem(&fresh).cost - b.cost), 1e-6 * b.cost);
}

TEST(BuilderTest, RebuildAssociationTermsRefusesWhatOnlyBuildCanDo) {
  const OwnedProblem problem = MakeTestProblem();
  const ProblemData data = problem.View();
  SolverState state = StateOf(problem);
  {
    SCOPED_TRACE("no problem yet");
    const SolverOptions options = SolverOptions::Preset("robust");
    ProblemBuilder builder(data, options, &state);
    EXPECT_FALSE(builder.RebuildAssociationTerms());
  }
  {
    SCOPED_TRACE("poses that only the walls reach (the prior anchors the poses before it)");
    const SolverOptions options = RobustOnly({TermIndex("W"), TermIndex("prior")});
    ProblemBuilder builder(data, options, &state);
    Associate(problem, 0, &state);
    builder.Build();
    ASSERT_GT(builder.terms()[TermIndex("W")].num_residual_blocks, 0);
    Associate(problem, 3, &state);
    EXPECT_FALSE(builder.RebuildAssociationTerms());
  }
  {
    SCOPED_TRACE("a pose the walls reached alone, which the new association leaves out");
    // A frame with wall points, its floor points left out.
    const int alone = problem.wall_frame[problem.wall_frame.size() / 2];
    ASSERT_NE(alone, 0);
    OwnedProblem cut = problem;
    cut.floor_frame.clear();
    cut.floor_plane.clear();
    cut.floor_p_in_cam.clear();
    for (size_t i = 0; i < problem.floor_frame.size(); ++i) {
      if (problem.floor_frame[i] == alone) continue;
      cut.floor_frame.push_back(problem.floor_frame[i]);
      cut.floor_plane.push_back(problem.floor_plane[i]);
      for (int k = 0; k < 3; ++k) cut.floor_p_in_cam.push_back(problem.floor_p_in_cam[3 * i + k]);
    }
    const ProblemData view = cut.View();
    SolverState s = StateOf(cut);
    const SolverOptions options = RobustOnly({TermIndex("F"), TermIndex("W"), TermIndex("prior")});
    ProblemBuilder builder(view, options, &s);
    Associate(cut, 1, &s);
    builder.Build();
    ASSERT_TRUE(builder.problem().HasParameterBlock(builder.Pose(alone)));  // by the walls
    Associate(cut, 3, &s, alone);
    EXPECT_FALSE(builder.RebuildAssociationTerms());
  }
}

}  // namespace
}  // namespace bimcap
