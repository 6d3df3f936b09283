// Manifold invariants (ceres/manifold_test_utils.h) of the pose and plane manifolds, and what the
// rotation- / translation-only modes hold fixed.
#include <ceres/manifold_test_utils.h>
#include <gtest/gtest.h>

#include <random>

#include "bimcap/pose.h"

namespace bimcap {
namespace {
// EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD names ceres helpers unqualified.
using namespace ceres;  // NOLINT(build/namespaces)

Eigen::Matrix<double, 7, 1> RandomPose(std::mt19937* rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Matrix<double, 7, 1> x;
  Eigen::Quaterniond q(g(*rng), g(*rng), g(*rng), g(*rng));
  q.normalize();
  x << g(*rng), g(*rng), g(*rng), q.x(), q.y(), q.z(), q.w();
  return x;
}

TEST(PoseManifold, InvariantsHoldInEveryMode) {
  std::mt19937 rng(7);
  std::normal_distribution<double> g(0.0, 1.0);
  for (RefineMode mode : {RefineMode::kFull, RefineMode::kRotation, RefineMode::kTranslation}) {
    const std::unique_ptr<ceres::Manifold> owned = CreatePoseManifold(mode);
    const ceres::Manifold& manifold = *owned;
    EXPECT_EQ(manifold.AmbientSize(), 7);
    EXPECT_EQ(manifold.TangentSize(), mode == RefineMode::kFull ? 6 : 3);
    for (int trial = 0; trial < 5; ++trial) {
      const Eigen::VectorXd x = RandomPose(&rng);
      Eigen::VectorXd delta(manifold.TangentSize());
      for (int k = 0; k < delta.size(); ++k) delta[k] = 0.3 * g(rng);
      Eigen::VectorXd y(7);
      ASSERT_TRUE(manifold.Plus(x.data(), delta.data(), y.data()));
      EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, x, delta, y, 1e-9);
    }
  }
}

TEST(PoseManifold, PlusKeepsUnitQuaternionAndHeldParts) {
  std::mt19937 rng(3);
  const Eigen::Matrix<double, 7, 1> x = RandomPose(&rng);
  Eigen::Matrix<double, 7, 1> y;
  const double full[6] = {0.1, -0.2, 0.3, 0.2, 0.1, -0.3};
  CreatePoseManifold(RefineMode::kFull)->Plus(x.data(), full, y.data());
  EXPECT_NEAR(y.tail<4>().norm(), 1.0, 1e-12);
  EXPECT_NEAR(y[0], x[0] + 0.1, 1e-12);

  const double three[3] = {0.2, 0.1, -0.3};
  CreatePoseManifold(RefineMode::kRotation)->Plus(x.data(), three, y.data());
  EXPECT_EQ(y.head<3>(), x.head<3>());  // translation held
  EXPECT_GT((y.tail<4>() - x.tail<4>()).norm(), 1e-3);
  CreatePoseManifold(RefineMode::kTranslation)->Plus(x.data(), three, y.data());
  EXPECT_EQ(y.tail<4>(), x.tail<4>());  // rotation held
  EXPECT_NEAR(y[2], x[2] - 0.3, 1e-12);
}

TEST(PlaneManifold, InvariantsAndUnitNormal) {
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  const std::unique_ptr<ceres::Manifold> owned = CreatePlaneManifold();
  const ceres::Manifold& manifold = *owned;
  EXPECT_EQ(manifold.AmbientSize(), 4);
  EXPECT_EQ(manifold.TangentSize(), 3);
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::Vector4d x(g(rng), g(rng), g(rng), g(rng));
    x.head<3>().normalize();
    Eigen::VectorXd delta(3);
    delta << 0.2 * g(rng), 0.2 * g(rng), 0.2 * g(rng);
    Eigen::VectorXd y(4);
    ASSERT_TRUE(manifold.Plus(x.data(), delta.data(), y.data()));
    EXPECT_NEAR(y.head<3>().norm(), 1.0, 1e-12);
    EXPECT_NEAR(y[3], x[3] + delta[2], 1e-12);
    const Eigen::VectorXd xv = x;
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, xv, delta, y, 1e-9);
  }
}

}  // namespace
}  // namespace bimcap
