// BatchedCostFunction's compressed form against its row form, through ceres::Problem::Evaluate:
// the cost, the tangent-space gradient and Gauss-Newton matrix Ceres sees must be the same.
#include "bimcap/cost_functions/batched.h"

#include <ceres/autodiff_cost_function.h>
#include <ceres/crs_matrix.h>
#include <ceres/loss_function.h>
#include <ceres/problem.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "bimcap/cost_functions/point_to_plane.h"
#include "bimcap/cost_functions/point_to_segment.h"
#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/pose.h"
#include "test_problems.h"

namespace bimcap {
namespace {

using Blocks = std::vector<std::vector<double>>;

// What Ceres sees of one problem: cost, gradient and JᵀJ in the tangent space (dense).
struct Seen {
  double cost = 0.0;
  double residual_only_cost = 0.0;
  std::vector<double> gradient;
  Eigen::MatrixXd jtj;
  int num_residuals = 0;
  bool compressed = false;
};

// The n observations `make(i)` on copies of `blocks`, in one BatchedCostFunction (`compress`),
// the manifolds on the parameter blocks, `constant` blocks held constant.
// The batch filled by `fill`, on copies of `blocks` (as Evaluate below).
Seen EvaluateFilled(const std::function<void(BatchedCostFunction*)>& fill, int k,
                    const ceres::LossFunction* loss, Blocks blocks,
                    const std::vector<const ceres::Manifold*>& manifolds,
                    const std::vector<bool>& constant, bool compress) {
  ceres::Problem::Options options;
  options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(options);
  auto* batched = new BatchedCostFunction(loss, k, manifolds, compress);
  fill(batched);
  std::vector<double*> pointers;
  for (auto& b : blocks) pointers.push_back(b.data());
  problem.AddResidualBlock(batched, nullptr, pointers);
  for (size_t b = 0; b < blocks.size(); ++b) {
    if (manifolds[b] != nullptr) {
      problem.SetManifold(pointers[b], const_cast<ceres::Manifold*>(manifolds[b]));
    }
    if (constant[b]) problem.SetParameterBlockConstant(pointers[b]);
  }
  Seen seen;
  seen.num_residuals = batched->num_residuals();
  seen.compressed = batched->compressed();
  ceres::CRSMatrix jacobian;
  EXPECT_TRUE(problem.Evaluate(ceres::Problem::EvaluateOptions(), &seen.cost, nullptr,
                               &seen.gradient, &jacobian));
  EXPECT_TRUE(problem.Evaluate(ceres::Problem::EvaluateOptions(), &seen.residual_only_cost, nullptr,
                               nullptr, nullptr));
  seen.jtj = testing::DenseJtJ(jacobian);
  return seen;
}

Seen Evaluate(const std::function<ceres::CostFunction*(int)>& make, int n, int k,
              const ceres::LossFunction* loss, Blocks blocks,
              const std::vector<const ceres::Manifold*>& manifolds,
              const std::vector<bool>& constant, bool compress) {
  const auto fill = [&](BatchedCostFunction* batched) {
    for (int i = 0; i < n; ++i) batched->Add(std::unique_ptr<ceres::CostFunction>(make(i)), i);
  };
  return EvaluateFilled(fill, k, loss, std::move(blocks), manifolds, constant, compress);
}

// What Ceres sees of `actual` is `expected`'s to rounding: the cost (both evaluations) to 1e-12,
// the gradient and JᵀJ to `tolerance` of their largest entries.
void ExpectSameModel(const Seen& expected, const Seen& actual, double tolerance) {
  EXPECT_GT(expected.cost, 0.0);
  EXPECT_NEAR(actual.cost, expected.cost, 1e-12 * expected.cost);
  EXPECT_NEAR(actual.residual_only_cost, expected.cost, 1e-12 * expected.cost);
  ASSERT_EQ(actual.gradient.size(), expected.gradient.size());
  double g_max = 0.0;
  for (double v : expected.gradient) g_max = std::max(g_max, std::abs(v));
  EXPECT_GT(g_max, 0.0);
  for (size_t a = 0; a < expected.gradient.size(); ++a) {
    EXPECT_NEAR(actual.gradient[a], expected.gradient[a], tolerance * g_max) << "gradient " << a;
  }
  ASSERT_EQ(actual.jtj.rows(), expected.jtj.rows());
  const double h_max = expected.jtj.cwiseAbs().maxCoeff();
  EXPECT_GT(h_max, 0.0);
  EXPECT_LE((actual.jtj - expected.jtj).cwiseAbs().maxCoeff(), tolerance * h_max);
}

// Both forms of the same batch; returns the compressed one's view. `model_size`: the compressed
// form's rows before the last (T, or 6 for a model of the relative pose).
Seen ExpectSameStepFilled(const std::function<void(BatchedCostFunction*)>& fill, int n, int k,
                          const ceres::LossFunction* loss, const Blocks& blocks,
                          const std::vector<const ceres::Manifold*>& manifolds,
                          const std::vector<bool>& constant, int model_size) {
  const Seen rows = EvaluateFilled(fill, k, loss, blocks, manifolds, constant, false);
  const Seen compressed = EvaluateFilled(fill, k, loss, blocks, manifolds, constant, true);
  EXPECT_FALSE(rows.compressed);
  EXPECT_TRUE(compressed.compressed);
  EXPECT_EQ(compressed.num_residuals, model_size + 1);
  EXPECT_EQ(rows.num_residuals, n * k + (loss != nullptr ? 1 : 0));
  EXPECT_NEAR(rows.residual_only_cost, rows.cost, 1e-12 * rows.cost);
  ExpectSameModel(rows, compressed, 1e-10);
  return compressed;
}

// The same for n observations `make(i)` added as cost functions.
Seen ExpectSameStep(const std::function<ceres::CostFunction*(int)>& make, int n, int k,
                    const ceres::LossFunction* loss, const Blocks& blocks,
                    const std::vector<const ceres::Manifold*>& manifolds,
                    const std::vector<bool>& constant, int model_size) {
  const auto fill = [&](BatchedCostFunction* batched) {
    for (int i = 0; i < n; ++i) batched->Add(std::unique_ptr<ceres::CostFunction>(make(i)), i);
  };
  return ExpectSameStepFilled(fill, n, k, loss, blocks, manifolds, constant, model_size);
}

std::vector<double> RandomPose(std::mt19937* rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  const Eigen::Quaterniond q =
      Eigen::Quaterniond(4.0 + g(*rng), g(*rng), g(*rng), g(*rng)).normalized();
  return {g(*rng), g(*rng), g(*rng), q.x(), q.y(), q.z(), q.w()};
}

TEST(Batched, CompressedReprojectionMatchesRows) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::vector<double> a = RandomPose(&rng);
  std::vector<double> b = a;
  b[0] += 0.3;  // the second frame 30 cm along x, slightly turned
  b[4] += 0.02;
  Eigen::Map<Eigen::Quaterniond>(b.data() + 3).normalize();
  const Eigen::Vector4d intrinsics(500.0, 500.0, 320.0, 240.0);
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> uvs;
  for (int i = 0; i < 50; ++i) {
    points.emplace_back(g(rng), g(rng), 3.0 + std::abs(g(rng)));
    // Outliers among them: the Cauchy loss is in its non-convex part for some.
    uvs.emplace_back(320.0 + 100.0 * g(rng), 240.0 + 100.0 * g(rng));
  }
  const ReprojectionModel model{intrinsics, 0.5, 2.0, 0.02};
  // The first n as data (what the builder makes), or as cost functions.
  const auto fill = [&](int n) {
    return [&, n](BatchedCostFunction* batched) {
      for (int i = 0; i < n; ++i) batched->AddReprojection(model, {points[i], uvs[i]}, i);
    };
  };
  const auto make = [&](int i) { return new ReprojectionCostFunction(model, {points[i], uvs[i]}); };
  ceres::CauchyLoss cauchy(1.0);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const std::unique_ptr<ceres::Manifold> rotation = CreatePoseManifold(RefineMode::kRotation);
  // On full pose manifolds the model is the relative pose's (6 rows + 1), mapped to both poses.
  {
    SCOPED_TRACE("two free poses");
    ExpectSameStepFilled(fill(50), 50, 2, &cauchy, {a, b}, {full.get(), full.get()}, {false, false},
                         6);
  }
  {
    SCOPED_TRACE("the first pose constant");
    ExpectSameStepFilled(fill(50), 50, 2, &cauchy, {a, b}, {full.get(), full.get()}, {true, false},
                         6);
  }
  {
    SCOPED_TRACE("the second pose constant");
    ExpectSameStepFilled(fill(50), 50, 2, &cauchy, {a, b}, {full.get(), full.get()}, {false, true},
                         6);
  }
  {
    SCOPED_TRACE("poses 40 m from the origin and 5 m apart");
    Blocks far = {a, b};
    far[0][0] += 40.0;
    far[1][0] += 45.0;
    far[1][1] -= 3.0;
    ExpectSameStepFilled(fill(50), 50, 2, &cauchy, far, {full.get(), full.get()}, {false, false},
                         6);
  }
  {
    SCOPED_TRACE("rotations only");
    ExpectSameStepFilled(fill(50), 50, 2, &cauchy, {a, b}, {rotation.get(), rotation.get()},
                         {false, false}, 6);
  }
  {
    SCOPED_TRACE("no loss");
    ExpectSameStepFilled(fill(50), 50, 2, nullptr, {a, b}, {full.get(), full.get()}, {false, false},
                         6);
  }
  {
    SCOPED_TRACE("no more rows than the relative pose's 6: the row form");
    const Seen seen =
        EvaluateFilled(fill(3), 2, &cauchy, {a, b}, {full.get(), full.get()}, {false, false}, true);
    EXPECT_EQ(seen.num_residuals, 7);
    EXPECT_FALSE(seen.compressed);
    ExpectSameStepFilled(fill(4), 4, 2, &cauchy, {a, b}, {full.get(), full.get()}, {false, false},
                         6);
  }
  {
    SCOPED_TRACE("as cost functions: both poses' tangent columns (12 rows + 1)");
    ExpectSameStep(make, 50, 2, &cauchy, {a, b}, {full.get(), full.get()}, {false, false}, 12);
  }
}

// G's reprojections kept as data (AddReprojection, what the builder makes) give what the same
// observations as ReprojectionCostFunctions give: on full pose manifolds (the data in the
// relative form, summed in camera b's axes; the cost functions in both poses' tangent columns)
// the same cost, gradient and Gauss-Newton matrix to rounding, in every other form (on
// rotation-only manifolds: ambient Jacobians) the same bits.
TEST(Batched, ReprojectionsAsDataMatchCostFunctions) {
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::vector<double> a = RandomPose(&rng);
  std::vector<double> b = a;
  b[0] += 0.3;
  b[5] -= 0.03;
  Eigen::Map<Eigen::Quaterniond>(b.data() + 3).normalize();
  const ReprojectionModel model{Eigen::Vector4d(500.0, 490.0, 320.0, 240.0), 0.5, 2.0, 0.02};
  std::vector<ReprojectionObservation> observations;
  for (int i = 0; i < 50; ++i) {
    // One point behind camera a (no depth whitening) and outliers for the Cauchy loss.
    const double z = i == 7 ? -1.0 : 3.0 + std::abs(g(rng));
    observations.push_back({Eigen::Vector3d(g(rng), g(rng), z),
                            Eigen::Vector2d(320.0 + 100.0 * g(rng), 240.0 + 100.0 * g(rng))});
  }
  ceres::CauchyLoss cauchy(1.0);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const std::unique_ptr<ceres::Manifold> rotation = CreatePoseManifold(RefineMode::kRotation);
  struct Case {
    const char* what;
    int n;
    const ceres::LossFunction* loss;
    const ceres::Manifold* manifold;
    std::vector<bool> constant;
    bool compress;
    bool relative;  // the relative form: to rounding, else bit for bit
  };
  const std::vector<Case> cases = {
      {"compressed, relative", 50, &cauchy, full.get(), {false, false}, true, true},
      {"compressed, the first pose constant", 50, &cauchy, full.get(), {true, false}, true, true},
      {"compressed, the second pose constant", 50, &cauchy, full.get(), {false, true}, true, true},
      {"compressed, no loss", 50, nullptr, full.get(), {false, false}, true, true},
      {"ambient Jacobians", 50, &cauchy, rotation.get(), {false, false}, true, false},
      {"rows", 50, &cauchy, full.get(), {false, false}, false, false},
      {"too few for the compressed form", 3, &cauchy, full.get(), {false, false}, true, false},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    const auto as_costs = [&](BatchedCostFunction* batched) {
      for (int i = 0; i < c.n; ++i) {
        batched->Add(std::make_unique<ReprojectionCostFunction>(model, observations[i]), i);
      }
    };
    const auto as_data = [&](BatchedCostFunction* batched) {
      for (int i = 0; i < c.n; ++i) batched->AddReprojection(model, observations[i], i);
    };
    const std::vector<const ceres::Manifold*> manifolds = {c.manifold, c.manifold};
    const Seen x = EvaluateFilled(as_costs, 2, c.loss, {a, b}, manifolds, c.constant, c.compress);
    const Seen y = EvaluateFilled(as_data, 2, c.loss, {a, b}, manifolds, c.constant, c.compress);
    EXPECT_EQ(x.compressed, y.compressed);
    if (c.relative) {
      // Cost functions give both poses' tangent columns, the data the relative pose's.
      EXPECT_EQ(x.num_residuals, 13);
      EXPECT_EQ(y.num_residuals, 7);
    } else {
      EXPECT_EQ(x.num_residuals, y.num_residuals);
    }
    EXPECT_GT(x.cost, 0.0);
    if (!c.relative) {
      EXPECT_EQ(x.cost, y.cost);
      EXPECT_EQ(x.residual_only_cost, y.residual_only_cost);
      EXPECT_EQ(x.gradient, y.gradient);
      EXPECT_TRUE(x.jtj == y.jtj);
      continue;
    }
    ExpectSameModel(x, y, 1e-11);
  }
  // One observation alone, as ForEachObservation evaluates it.
  BatchedCostFunction batched(&cauchy, 2, {full.get(), full.get()});
  for (int i = 0; i < 5; ++i) batched.AddReprojection(model, observations[i], 10 + i);
  const double* blocks[2] = {a.data(), b.data()};
  for (int i = 0; i < 5; ++i) {
    double x[2], y[2];
    ASSERT_TRUE(batched.EvaluateSample(i, blocks, x));
    ASSERT_TRUE(ReprojectionCostFunction(model, observations[i]).Evaluate(blocks, y, nullptr));
    EXPECT_EQ(x[0], y[0]);
    EXPECT_EQ(x[1], y[1]);
    EXPECT_EQ(batched.sample_index(i), 10 + i);
  }
  // A batch holds one kind of observation and one model.
  ReprojectionModel other = model;
  other.intrinsics_b[0] += 1.0;
  EXPECT_THROW(batched.AddReprojection(other, observations[0], 0), std::logic_error);
  EXPECT_THROW(batched.Add(std::make_unique<ReprojectionCostFunction>(model, observations[0]), 0),
               std::logic_error);
}

// Nine residuals an observation: more than the compressed form's buffers take (kMaxK = 8).
struct NineResiduals {
  template <typename T>
  bool operator()(const T* pose, T* r) const {
    for (int i = 0; i < 9; ++i) r[i] = pose[i % 7] * T(1.0 + i) - T(0.1 * i);
    return true;
  }
};

TEST(Batched, LargerObservationsStayRows) {
  std::mt19937 rng(17);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const auto make = [](int) {
    return new ceres::AutoDiffCostFunction<NineResiduals, 9, kPoseSize>(new NineResiduals);
  };
  ceres::CauchyLoss cauchy(1.0);
  const Seen seen = Evaluate(make, 4, 9, &cauchy, {RandomPose(&rng)}, {full.get()}, {false}, true);
  EXPECT_FALSE(seen.compressed);
  EXPECT_EQ(seen.num_residuals, 4 * 9 + 1);
  EXPECT_GT(seen.cost, 0.0);
  EXPECT_NEAR(seen.residual_only_cost, seen.cost, 1e-12 * seen.cost);
}

// A floor point sees the pose's height, roll and pitch only: the compressed block must leave
// the other three tangent directions (x, y, yaw) as empty as the row form does, or
// Levenberg-Marquardt's diagonal floor turns their rounding into steps (compressing the
// 7-vector ambient Jacobians did: a wall-only solve turned by 33°, which
// SolverTest.WallAloneFixesPlanPositionAndYaw catches).
TEST(Batched, CompressedFloorLeavesUnseenDirectionsEmpty) {
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::vector<double> pose = RandomPose(&rng);
  const Eigen::Vector4d floor(0.0, 0.0, 1.0, 0.0);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 40; ++i) points.emplace_back(g(rng), g(rng), 2.0 + std::abs(g(rng)));
  const auto make = [&](int i) {
    return PointToPlaneCostFunction::Create(points[i], floor, 1.0 / 0.05);
  };
  ceres::CauchyLoss cauchy(1.0);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const Seen seen = ExpectSameStep(make, 40, 1, &cauchy, {pose}, {full.get()}, {false}, 6);
  const double h_max = seen.jtj.cwiseAbs().maxCoeff();
  for (const int unseen : {0, 1}) {  // δt_x, δt_y: exactly empty, as in the row form
    EXPECT_EQ(seen.jtj.row(unseen).cwiseAbs().maxCoeff(), 0.0) << unseen;
    EXPECT_EQ(seen.gradient[unseen], 0.0) << unseen;
  }
  // δθ_z: rounding only (the row form's is ~5e-18 of the largest entry here).
  EXPECT_LE(seen.jtj.row(5).cwiseAbs().maxCoeff(), 1e-15 * h_max);
  EXPECT_LE(std::abs(seen.gradient[5]), 1e-15 * h_max);
}

TEST(Batched, CompressedWithPlaneAndSegmentsMatchesRows) {
  std::mt19937 rng(9);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::vector<double> pose = RandomPose(&rng);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 30; ++i) points.emplace_back(g(rng), g(rng), 2.0 + std::abs(g(rng)));
  const Eigen::Vector3d n = Eigen::Vector3d(0.1, 0.2, 1.0).normalized();
  const std::vector<double> plane = {n.x(), n.y(), n.z(), -0.4};
  ceres::HuberLoss huber(0.5);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const std::unique_ptr<ceres::Manifold> plane_manifold = CreatePlaneManifold();
  {
    SCOPED_TRACE("a FACaP plane (sphere × line)");
    const auto make = [&](int i) {
      return PointToVariablePlaneCostFunctor::Create(points[i], 1.0 / 0.05);
    };
    ExpectSameStep(make, 30, 1, &huber, {pose, plane}, {full.get(), plane_manifold.get()},
                   {false, false}, 9);
  }
  {
    SCOPED_TRACE("wall segments");
    const auto make = [&](int i) {
      const Eigen::Vector4d segment(-1.0 + 0.1 * i, 2.0, 1.0, 2.5 - 0.05 * i);
      return PointToSegmentCostFunction::Create(points[i], segment, 1.0 / 0.05);
    };
    ExpectSameStep(make, 30, 1, &huber, {pose}, {full.get()}, {false}, 6);
  }
}

// EvaluateTangent against what Ceres would make of Evaluate: the ambient Jacobian times the
// kFull manifold's Plus Jacobian, at random poses, with and without the depth whitening, and
// behind camera b (zero residuals and Jacobian).
TEST(PoseTangent, ReprojectionIsAmbientTimesPlusJacobian) {
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  const Eigen::Vector4d intrinsics(500.0, 480.0, 320.0, 240.0);
  int behind = 0;
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<double> a = RandomPose(&rng), b = a;
    for (int k = 0; k < 3; ++k) b[k] += 0.3 * g(rng);
    for (int k = 3; k < 7; ++k) b[k] += 0.05 * g(rng);
    Eigen::Map<Eigen::Quaterniond>(b.data() + 3).normalize();
    const Eigen::Vector3d p_a(g(rng), g(rng), trial % 10 == 0 ? 0.2 : 2.0 + std::abs(g(rng)));
    const Eigen::Vector2d uv(320.0 + 50.0 * g(rng), 240.0 + 50.0 * g(rng));
    const double depth_sigma = trial % 2 == 0 ? 0.02 : 0.0;
    const std::unique_ptr<ReprojectionCostFunction> cost(static_cast<ReprojectionCostFunction*>(
        ReprojectionCostFunction::Create(p_a, uv, intrinsics, 0.5, 2.0, depth_sigma)));
    const double* blocks[2] = {a.data(), b.data()};
    double r_ambient[2], j_a[14], j_b[14];
    double* jacobians[2] = {j_a, j_b};
    ASSERT_TRUE(cost->Evaluate(blocks, r_ambient, jacobians));
    const PoseMatrix poses[2] = {PoseMatrix::FromBlock(a.data()), PoseMatrix::FromBlock(b.data())};
    double r_tangent[2], j_tangent[24], r_only[2];
    ASSERT_TRUE(cost->EvaluateTangent(poses, r_tangent, j_tangent));
    ASSERT_TRUE(cost->EvaluateTangent(poses, r_only, nullptr));
    if (r_ambient[0] == 0.0 && r_ambient[1] == 0.0) ++behind;
    double scale = 1e-300;
    for (int k = 0; k < 14; ++k) scale = std::max({scale, std::abs(j_a[k]), std::abs(j_b[k])});
    for (int i = 0; i < 2; ++i) {
      EXPECT_NEAR(r_tangent[i], r_ambient[i], 1e-11 * std::max(1.0, std::abs(r_ambient[i])));
      EXPECT_EQ(r_only[i], r_tangent[i]);
    }
    for (int block = 0; block < 2; ++block) {
      Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus;
      ASSERT_TRUE(full->PlusJacobian(blocks[block], plus.data()));
      const Eigen::Map<const Eigen::Matrix<double, 2, 7, Eigen::RowMajor>> ambient(
          jacobians[block]);
      const Eigen::Matrix<double, 2, 6> expected = ambient * plus;
      for (int i = 0; i < 2; ++i) {
        for (int c = 0; c < 6; ++c) {
          EXPECT_NEAR(j_tangent[12 * i + 6 * block + c], expected(i, c), 1e-10 * scale)
              << "trial " << trial << " block " << block << " row " << i << " col " << c;
        }
      }
    }
    // The residual depends on b⁻¹ a alone: pose b's columns from b⁻¹ a in camera b's axes
    // (EvaluateReprojectionInCameraB, times diag(R_bᵀ, R_bᵀ)), and pose a's are pose b's times
    // E_ab.
    double r_in_b[2], j_in_b[12], j_second[12], j_mapped[12];
    EvaluateReprojectionInCameraB(cost->model(), cost->observation(),
                                  RelativePose::Between(poses[0], poses[1]), r_in_b, j_in_b);
    const Eigen::Matrix3d rt = poses[1].rotation.transpose();
    for (int i = 0; i < 2; ++i) {
      const Eigen::Vector3d t = Eigen::Map<const Eigen::RowVector3d>(j_in_b + 6 * i) * rt;
      const Eigen::Vector3d th = Eigen::Map<const Eigen::RowVector3d>(j_in_b + 6 * i + 3) * rt;
      for (int k = 0; k < 3; ++k) {
        j_second[6 * i + k] = t[k];
        j_second[6 * i + 3 + k] = th[k];
      }
    }
    RelativeTangentMap(poses[0].translation - poses[1].translation, j_second, 2, 6, j_mapped);
    for (int i = 0; i < 2; ++i) {
      EXPECT_NEAR(r_in_b[i], r_tangent[i], 1e-11 * std::max(1.0, std::abs(r_tangent[i])));
      for (int c = 0; c < 6; ++c) {
        EXPECT_NEAR(j_second[6 * i + c], j_tangent[12 * i + 6 + c], 1e-10 * scale)
            << "trial " << trial << " row " << i << " col " << c;
        EXPECT_NEAR(j_mapped[6 * i + c], j_tangent[12 * i + c], 1e-10 * scale)
            << "trial " << trial << " row " << i << " col " << c;
      }
    }
  }
  EXPECT_GT(behind, 0);
}

// The same for the one-pose terms (F, Ce: point to plane; W, Co: point to segment, on both
// pieces of the distance: across the segment and past its ends).
TEST(PoseTangent, PlaneAndSegmentAreAmbientTimesPlusJacobian) {
  std::mt19937 rng(13);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::unique_ptr<ceres::Manifold> full = CreatePoseManifold(RefineMode::kFull);
  for (int trial = 0; trial < 200; ++trial) {
    const std::vector<double> pose = RandomPose(&rng);
    const Eigen::Vector3d p(g(rng), g(rng), 2.0 + std::abs(g(rng)));
    const Eigen::Vector3d n = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector4d segment(g(rng), g(rng), g(rng), g(rng));
    const std::unique_ptr<PoseTangentCostFunction> costs[2] = {
        std::unique_ptr<PoseTangentCostFunction>(
            static_cast<PointToPlaneCostFunction*>(PointToPlaneCostFunction::Create(
                p, Eigen::Vector4d(n.x(), n.y(), n.z(), g(rng)), 20.0))),
        std::unique_ptr<PoseTangentCostFunction>(static_cast<PointToSegmentCostFunction*>(
            PointToSegmentCostFunction::Create(p, segment, 20.0)))};
    const double* blocks[1] = {pose.data()};
    const PoseMatrix matrix = PoseMatrix::FromBlock(pose.data());
    Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus;
    ASSERT_TRUE(full->PlusJacobian(pose.data(), plus.data()));
    for (const auto& cost : costs) {
      double r_ambient, j_ambient[7], r_tangent, j_tangent[6];
      double* jacobians[1] = {j_ambient};
      ASSERT_TRUE(cost->Evaluate(blocks, &r_ambient, jacobians));
      ASSERT_TRUE(cost->EvaluateTangent(&matrix, &r_tangent, j_tangent));
      EXPECT_NEAR(r_tangent, r_ambient, 1e-11 * std::max(1.0, std::abs(r_ambient)));
      const Eigen::Matrix<double, 1, 6> expected =
          Eigen::Map<const Eigen::Matrix<double, 1, 7>>(j_ambient) * plus;
      const double scale = std::max(1.0, expected.cwiseAbs().maxCoeff());
      for (int c = 0; c < 6; ++c) {
        EXPECT_NEAR(j_tangent[c], expected(c), 1e-10 * scale) << "trial " << trial << " col " << c;
      }
    }
  }
}

}  // namespace
}  // namespace bimcap
