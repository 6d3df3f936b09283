// Association of wall points with floor-plan segments: nearest within the gate, z range, and the
// visibility test with free-side normals (a point never lands on the far face of its wall).
#include "bimcap/association.h"

#include <gtest/gtest.h>

#include <vector>

#include "bimcap/problem.h"
#include "test_problems.h"

namespace bimcap {
namespace {

// A 0.2 m thick wall along y: inner face x = 0 (free side +x, the room), outer face x = -0.2
// (free side -x, outdoors), both from y = -5 to 5, storey z in [0, 3].
struct ThickWall {
  std::vector<double> segments = {0.0, -5.0, 0.0, 5.0, -0.2, -5.0, -0.2, 5.0};
  std::vector<int32_t> segment_class = {kLabelWall, kLabelWall};
  std::vector<double> segment_z = {0.0, 3.0, 0.0, 3.0};
  std::vector<double> normals = {1.0, 0.0, -1.0, 0.0};

  ArrayRef<double> Segments() const { return {segments.data(), 2, 4}; }
  ArrayRef<int32_t> Classes() const { return {segment_class.data(), 2, 1}; }
  ArrayRef<double> Z() const { return {segment_z.data(), 2, 2}; }
  ArrayRef<double> Normals() const { return {normals.data(), 2, 2}; }
};

TEST(SegmentIndexTest, NearestFaceWithoutNormals) {
  const ThickWall w;
  const SegmentIndex index(w.Segments(), w.Classes(), w.Z(), ArrayRef<double>{}, kLabelWall, 0.5);
  double d = -1.0;
  // 0.15 m behind the inner face is 0.05 m from the outer one: the alias wins.
  EXPECT_EQ(index.Nearest(-0.15, 1.0, 1.5, 3.0, 1.0, &d), 1);
  EXPECT_NEAR(d, 0.05, 1e-12);
  EXPECT_EQ(index.Nearest(-0.05, 1.0, 1.5, 3.0, 1.0, &d), 0);
  EXPECT_EQ(index.Nearest(-0.05, 1.0, 3.5, 3.0, 1.0, &d), -1);  // above the storey
  EXPECT_EQ(index.Nearest(1.0, 1.0, 1.5, 3.0, 1.0, &d), -1);    // outside the gate
}

TEST(SegmentIndexTest, VisibilityKeepsTheFaceTheCameraSees) {
  const ThickWall w;
  const SegmentIndex index(w.Segments(), w.Classes(), w.Z(), w.Normals(), kLabelWall, 0.5);
  double d = -1.0;
  // Seen from inside the room (camera at x = 3) only the inner face is admissible.
  EXPECT_EQ(index.Nearest(-0.15, 1.0, 1.5, 3.0, 1.0, &d), 0);
  EXPECT_NEAR(d, 0.15, 1e-12);
  // Seen from outdoors (x = -4) only the outer face is.
  EXPECT_EQ(index.Nearest(-0.05, 1.0, 1.5, -4.0, 1.0, &d), 1);
  EXPECT_NEAR(d, 0.15, 1e-12);
  // A camera inside the wall sees neither face.
  EXPECT_EQ(index.Nearest(-0.1, 1.0, 1.5, -0.1, 1.0, &d), -1);
}

TEST(SegmentIndexTest, ZeroNormalIsSeenFromBothSides) {
  ThickWall w;
  w.normals = {0.0, 0.0, 0.0, 0.0};
  const SegmentIndex index(w.Segments(), w.Classes(), w.Z(), w.Normals(), kLabelWall, 0.5);
  double d = -1.0;
  EXPECT_EQ(index.Nearest(-0.15, 1.0, 1.5, 3.0, 1.0, &d), 1);
  EXPECT_EQ(index.Nearest(-0.05, 1.0, 1.5, -4.0, 1.0, &d), 0);
}

TEST(AssociatePointsTest, UsesEachPointsCameraCentre) {
  const ThickWall w;
  const SegmentIndex index(w.Segments(), w.Classes(), w.Z(), w.Normals(), kLabelWall, 0.5);
  // Two identity-rotation cameras, one in the room and one outdoors; each sees a point 0.15 m
  // beyond the face in front of it (a noisy or drifted return).
  const std::vector<double> poses = {3.0, 0.0, 1.5, 0, 0, 0, 1, -4.0, 0.0, 1.5, 0, 0, 0, 1};
  const std::vector<int32_t> frame = {0, 1};
  const std::vector<double> p_in_cam = {-3.15, 0.0, 0.0, 3.95, 0.0, 0.0};
  AssociationStats stats;
  const std::vector<int> assoc = AssociatePoints(index, {frame.data(), 2, 1},
                                                 {p_in_cam.data(), 2, 3}, poses.data(), {}, &stats);
  ASSERT_EQ(assoc.size(), 2u);
  EXPECT_EQ(assoc[0], 0);
  EXPECT_EQ(assoc[1], 1);
  EXPECT_EQ(stats.num_associated, 2);
  EXPECT_NEAR(stats.mean_distance, 0.15, 1e-12);
}

TEST(ValidateProblemTest, SegmentNormalIsOptionalUnitOrZero) {
  const testing::OwnedProblem owned = testing::MakeTestProblem();
  ProblemData data = owned.View();
  const int64_t s = data.F64("segments").rows;
  ASSERT_GT(s, 0);
  ValidateProblem(data);  // absent: fine
  std::vector<double> normals(2 * s, 0.0);
  normals[0] = 1.0;
  data.Set("segment_normal", ArrayRef<double>{normals.data(), s, 2});
  ValidateProblem(data);  // unit or zero: fine
  normals[2] = 0.5;
  try {
    ValidateProblem(data);
    FAIL() << "a normal of norm 0.5 was accepted";
  } catch (const ProblemError& e) {
    EXPECT_EQ(e.field(), "segment_normal");
  }
  data.Set("segment_normal", ArrayRef<double>{normals.data(), s - 1, 2});
  EXPECT_THROW(ValidateProblem(data), ProblemError);  // one row per segment
}

}  // namespace
}  // namespace bimcap
