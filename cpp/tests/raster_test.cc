// The completion's raster (bimcap/raster/): the expected images were drawn by OpenCV 5.0's
// cv2.fillConvexPoly(image, corners, id, cv2.LINE_8, 4) (tests/test_frontend_speed.py compares
// the two on random and real triangles); the affine values and plane depths are computed by
// hand (the same file compares them with numpy).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "bimcap/raster/component_pixels.h"
#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/depth_normals.h"
#include "bimcap/raster/gray.h"
#include "bimcap/raster/near_region.h"
#include "bimcap/raster/piecewise_affine.h"
#include "bimcap/raster/pixel_neighbours.h"
#include "bimcap/raster/plane_depth.h"
#include "bimcap/raster/plane_scores.h"
#include "bimcap/raster/png_rows.h"
#include "bimcap/raster/point_neighbours.h"
#include "bimcap/raster/range_noise.h"
#include "bimcap/raster/voxel_normals.h"

namespace bimcap::raster {
namespace {

// An image as rows of characters: '.' for 0, '0' + v for v.
std::vector<std::string> Text(const std::vector<int32_t>& pixels, int rows, int cols) {
  std::vector<std::string> out(rows, std::string(cols, '.'));
  for (int v = 0; v < rows; ++v) {
    for (int u = 0; u < cols; ++u) {
      const int32_t p = pixels[v * cols + u];
      if (p != 0) out[v][u] = static_cast<char>('0' + p);
    }
  }
  return out;
}

std::vector<std::string> Draw(int rows, int cols, const std::vector<int32_t>& corners,
                              const std::vector<int32_t>& ids) {
  std::vector<int32_t> pixels(rows * cols, 0);
  FillTriangleIds({pixels.data(), rows, cols}, corners.data(), ids.data(),
                  static_cast<int64_t>(ids.size()), 4);
  return Text(pixels, rows, cols);
}

TEST(ConvexFill, TwoTrianglesSharingAnEdgeAsOpenCV) {
  // (1.3, 0.6) (9.7, 2.2) (3.1, 8.4), then (9.7, 2.2) (11.4, 9.1) (3.1, 8.4): the second
  // overwrites the shared edge's pixels.
  const std::vector<std::string> expected = {
      "............",  //
      ".11111......",  //
      "..111111112.",  //
      "..111111122.",  //
      "..111111222.",  //
      "..111122222.",  //
      "..1112222222",  //
      "...122222222",  //
      "...222222222",  //
      ".....2222222",  //
  };
  EXPECT_EQ(Draw(10, 12, {21, 10, 155, 35, 50, 134, 155, 35, 182, 146, 50, 134}, {1, 2}), expected);
}

TEST(ConvexFill, TrianglePartlyOutsideAsOpenCV) {
  // (−2.5, −1.5) (9.375, 1.875) (1.25, 8.125) on an 8 × 6 image: the outline is clipped
  // (the gap in row 0 is OpenCV's too).
  const std::vector<std::string> expected = {
      "33.33...",  //
      "33333333",  //
      "33333333",  //
      "33333333",  //
      "33333333",  //
      "333333..",  //
  };
  EXPECT_EQ(Draw(6, 8, {-40, -24, 150, 30, 20, 130}, {3}), expected);
}

TEST(ConvexFill, SliverIsItsOutline) {
  const std::vector<std::string> expected = {
      "........",  //
      ".4444...",  //
      "....4444",  //
      ".......4",  //
      "........",  //
      "........",  //
  };
  EXPECT_EQ(Draw(6, 8, {8, 8, 110, 40, 111, 41}, {4}), expected);
}

TEST(ConvexFill, AxisAlignedSquareCoversItsPixels) {
  // Corners at pixel centres (1, 1) and (4, 3): rows 1–3, columns 1–4 inclusive.
  std::vector<int32_t> pixels(5 * 6, 0);
  const int32_t square[] = {16, 16, 64, 16, 64, 48, 16, 48};
  FillConvexPolygon({pixels.data(), 5, 6}, square, 4, 7, 4);
  const std::vector<std::string> expected = {"......", ".7777.", ".7777.", ".7777.", "......"};
  EXPECT_EQ(Text(pixels, 5, 6), expected);
}

TEST(ConvexFill, OutsideTheImageDrawsNothing) {
  std::vector<int32_t> pixels(4 * 4, 0);
  const int32_t far[] = {1000, 1000, 1200, 1000, 1100, 1300};
  const int32_t ids[] = {5};
  FillTriangleIds({pixels.data(), 4, 4}, far, ids, 1, 4);
  for (int32_t p : pixels) EXPECT_EQ(p, 0);
  const int32_t above[] = {-100, -900, 300, -900, 100, -200};
  FillTriangleIds({pixels.data(), 4, 4}, above, ids, 1, 4);
  for (int32_t p : pixels) EXPECT_EQ(p, 0);
}

TEST(ConvexFill, RejectsAShiftOpenCvDrawsOtherwise) {
  std::vector<int32_t> pixels(4, 0);
  const int32_t tri[] = {0, 0, 1, 0, 0, 1};
  const int32_t ids[] = {1};
  EXPECT_THROW(FillTriangleIds({pixels.data(), 2, 2}, tri, ids, 1, 0), RasterError);
  EXPECT_THROW(FillTriangleIds({pixels.data(), 2, 2}, tri, ids, 1, 17), RasterError);
  try {
    FillConvexPolygon({pixels.data(), 2, 2}, tri, 3, 1, -1);
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "shift");
  }
}

TEST(ConvexFill, RejectsCoordinatesBeyondTheFixedPointRange) {
  // Within ±2^14 px the 16.16 products of the clipping fit in int64; beyond, nothing is drawn.
  std::vector<int32_t> pixels(4 * 4, 0);
  const int32_t tris[] = {0, 0, 32, 0, 0, 32, 0, 0, 32, 0, 0, (16384 + 1) * 16};
  const int32_t ids[] = {1, 2};
  try {
    FillTriangleIds({pixels.data(), 4, 4}, tris, ids, 2, 4);
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "corners");
    EXPECT_NE(std::string(e.what()).find("triangle 1"), std::string::npos);
  }
  for (int32_t p : pixels) EXPECT_EQ(p, 0);  // checked before the first was drawn
  const int32_t edge[] = {-16384 * 16, 0, 16384 * 16, 0, 0, 16384 * 16};
  EXPECT_NO_THROW(FillTriangleIds({pixels.data(), 4, 4}, edge, ids, 1, 4));
  EXPECT_THROW(FillTriangleIds({pixels.data(), 16385, 1}, edge, ids, 0, 4), RasterError);
}

std::vector<int32_t> Contained(int64_t rows, int64_t cols, const std::vector<int32_t>& corners,
                               const std::vector<int32_t>& ids) {
  std::vector<int32_t> pixels(rows * cols, 0);
  FillContainingTriangleIds({pixels.data(), rows, cols}, corners.data(), ids.data(),
                            static_cast<int64_t>(ids.size()), 4);
  return pixels;
}

TEST(ContainingTriangles, SquareSplitOnAPixelDiagonalEachCentreOnce) {
  // The square (0, 0) – (6, 6) px split along its diagonal, which runs through the pixel
  // centres (k, k). A centre p is read as p + (ε₁, ε₂), 0 < ε₂ ≪ ε₁: the square holds the
  // centres 0 ≤ u, v < 6, each in one triangle, in either order and with either winding; the
  // diagonal's centres lie right of it, in the upper triangle.
  const std::vector<int32_t> lower = {0, 0, 96, 96, 0, 96};  // (0,0) (6,6) (0,6)
  const std::vector<int32_t> upper = {0, 0, 96, 0, 96, 96};  // (0,0) (6,0) (6,6)
  std::vector<int32_t> both = lower, reversed = upper;
  both.insert(both.end(), upper.begin(), upper.end());
  reversed.insert(reversed.end(), lower.begin(), lower.end());
  const auto ab = Contained(8, 8, both, {1, 2});
  EXPECT_EQ(Contained(8, 8, reversed, {2, 1}), ab);
  // a clockwise copy of the lower triangle holds the same centres
  const auto lower_only = Contained(8, 8, lower, {1});
  EXPECT_EQ(Contained(8, 8, {0, 0, 0, 96, 96, 96}, {1}), lower_only);
  const auto upper_only = Contained(8, 8, upper, {2});
  for (int v = 0; v < 8; ++v) {
    for (int u = 0; u < 8; ++u) {
      const int i = v * 8 + u;
      const bool in_square = u < 6 && v < 6;
      EXPECT_EQ((lower_only[i] != 0) + (upper_only[i] != 0), in_square ? 1 : 0) << u << "," << v;
      EXPECT_EQ(ab[i], in_square ? (v > u ? 1 : 2) : 0) << u << "," << v;
    }
  }
}

TEST(ContainingTriangles, FanAroundAPixelCentreOwnsItOnce) {
  // Six triangles around the centre (4, 4), their edges through it along the axes and the
  // diagonals: that centre, and each centre on a spoke, belongs to exactly one of them.
  const int32_t c = 64, r = 48;  // (4, 4) and 3 px, in 1/16 px
  const std::vector<std::pair<int32_t, int32_t>> rim = {{c + r, c}, {c + r, c + r}, {c, c + r},
                                                        {c - r, c}, {c - r, c - r}, {c, c - r}};
  std::vector<int32_t> pixels(9 * 9, 0);
  std::vector<int32_t> count(9 * 9, 0);
  for (size_t t = 0; t < rim.size(); ++t) {
    const auto& [x1, y1] = rim[t];
    const auto& [x2, y2] = rim[(t + 1) % rim.size()];
    const auto one = Contained(9, 9, {c, c, x1, y1, x2, y2}, {static_cast<int32_t>(t + 1)});
    for (size_t i = 0; i < one.size(); ++i) count[i] += one[i] != 0;
  }
  EXPECT_EQ(count[4 * 9 + 4], 1);
  for (int k = 1; k <= 2; ++k) {  // centres on the spokes, inside the fan
    EXPECT_EQ(count[4 * 9 + 4 + k], 1) << k;
    EXPECT_EQ(count[(4 + k) * 9 + 4 + k], 1) << k;
    EXPECT_EQ(count[(4 - k) * 9 + 4], 1) << k;
  }
  for (int32_t n : count) EXPECT_LE(n, 1);
}

TEST(ContainingTriangles, DegenerateAndOutsideDrawNothingBadInputThrows) {
  std::vector<int32_t> pixels(4 * 4, 0);
  const int32_t line[] = {0, 0, 16, 16, 32, 32};
  const int32_t ids[] = {7};
  FillContainingTriangleIds({pixels.data(), 4, 4}, line, ids, 1, 4);
  const int32_t far[] = {1000, 1000, 1200, 1000, 1100, 1300};
  FillContainingTriangleIds({pixels.data(), 4, 4}, far, ids, 1, 4);
  for (int32_t p : pixels) EXPECT_EQ(p, 0);
  // a triangle that holds no pixel centre (inside one pixel) draws nothing either
  const int32_t tiny[] = {18, 18, 26, 18, 18, 26};
  FillContainingTriangleIds({pixels.data(), 4, 4}, tiny, ids, 1, 4);
  for (int32_t p : pixels) EXPECT_EQ(p, 0);
  const int32_t tris[] = {0, 0, 32, 0, 0, 32, 0, 0, 32, 0, 0, (16384 + 1) * 16};
  const int32_t two[] = {1, 2};
  try {
    FillContainingTriangleIds({pixels.data(), 4, 4}, tris, two, 2, 4);
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "corners");
  }
  for (int32_t p : pixels) EXPECT_EQ(p, 0);  // checked before drawing
  EXPECT_THROW(FillContainingTriangleIds({pixels.data(), 4, 4}, line, ids, 1, 0), RasterError);
}

TEST(PiecewiseAffine, ValuesInNumpysOrder) {
  // 2 × 3 ids: column 0 of the table is "no triangle"; f = c0 u + c1 v + c2.
  const int32_t ids[] = {0, 1, 1, 2, 2, 0};
  const double coef[] = {0.0, 0.25,  -1.0,  // c0
                         0.0, 0.5,   2.0,   // c1
                         0.0, 0.125, 0.5};  // c2
  float out[6];
  EvaluatePiecewiseAffine({ids, 2, 3}, coef, 3, AffineValue::kDepth, {out, 2, 3});
  EXPECT_EQ(out[0], 0.0f);
  EXPECT_EQ(out[1], 0.375f);           // 0.25·1 + 0 + 0.125
  EXPECT_EQ(out[2], 0.625f);           // 0.25·2 + 0 + 0.125
  EXPECT_EQ(out[3], 2.5f);             // −1·0 + 2·1 + 0.5
  EXPECT_EQ(out[4], 1.5f);             // −1·1 + 2·1 + 0.5
  EXPECT_FALSE(std::signbit(out[5]));  // no triangle: +0
  EvaluatePiecewiseAffine({ids, 2, 3}, coef, 3, AffineValue::kInverseDepth, {out, 2, 3});
  EXPECT_EQ(out[0], 0.0f);
  EXPECT_EQ(out[1], static_cast<float>(1.0 / 0.375));
  EXPECT_EQ(out[4], static_cast<float>(1.0 / 1.5));
  // A negative f: depth clamps at +0, inverse depth gives 0.
  const double negative[] = {0.0, -1.0, 0.0, 0.0, 0.0, -0.0};
  const int32_t one[] = {1};
  EvaluatePiecewiseAffine({one, 1, 1}, negative, 2, AffineValue::kDepth, {out, 1, 1});
  EXPECT_EQ(out[0], 0.0f);
  EXPECT_FALSE(std::signbit(out[0]));
  // f = (1e-300 · 0) + 0 + 1e-300 > 0: 1 / max(f, 1e-12) = 1e12, not 1e300.
  const double tiny[] = {0.0, 1e-300, 0.0, 0.0, 0.0, 1e-300};
  EvaluatePiecewiseAffine({one, 1, 1}, tiny, 2, AffineValue::kInverseDepth, {out, 1, 1});
  EXPECT_EQ(out[0], static_cast<float>(1.0 / 1e-12));
}

TEST(PiecewiseAffine, RejectsIdsOutsideTheTable) {
  const int32_t ids[] = {0, 3};
  const double coef[] = {0, 1, 0, 1, 0, 1};
  float out[2];
  try {
    EvaluatePiecewiseAffine({ids, 1, 2}, coef, 2, AffineValue::kDepth, {out, 1, 2});
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "tri_id");
    EXPECT_NE(std::string(e.what()).find("id 3 at row 0, column 1"), std::string::npos);
  }
  const int32_t negative[] = {-1};
  EXPECT_THROW(EvaluatePiecewiseAffine({negative, 1, 1}, coef, 2, AffineValue::kDepth, {out, 1, 1}),
               RasterError);
  EXPECT_THROW(EvaluatePiecewiseAffine({ids, 1, 2}, coef, 2, AffineValue::kDepth, {out, 2, 1}),
               RasterError);
}

TEST(PlaneDepth, OnePlaneMovesEveryPixelWithinTheChangeLimit) {
  // The plane z = 2 (n = (0, 0, 1), d = −2) tilted: n = (0.6, 0, 0.8), d = −1.6, so that along
  // the ray (x, y, 1) z = 1.6 / (0.6 x + 0.8).
  const double x[] = {0.0, 0.5, -0.5, 0.25};
  const double y[] = {0.0, 0.0, 1.0, -1.0};
  const double depth[] = {2.1, 1.5, 2.0, 1.0};
  const int64_t flat[] = {4, 0, 2, 1};
  const double plane[] = {0.6, 0.0, 0.8, -1.6};
  float out[5] = {9, 9, 9, 9, 9};
  const int64_t moved =
      MoveOntoPlanes({x, y, depth, flat, 4}, plane, 1, nullptr, {0.08, 0.15}, out, 5);
  EXPECT_EQ(moved, 2);
  EXPECT_EQ(out[4], static_cast<float>(-(-1.6) / (0.0 * 0.6 + 0.0 * 0.0 + 0.8)));  // 2: 5 % off
  EXPECT_EQ(out[0], static_cast<float>(1.6 / (0.5 * 0.6 + 0.0 + 0.8)));  // 1.4545…: 3 % off
  EXPECT_EQ(out[2], 9.0f);  // 1.6 / 0.5 = 3.2: 60 % off
  EXPECT_EQ(out[1], 9.0f);  // 1.6 / 0.95 = 1.68: 68 % off
  EXPECT_EQ(out[3], 9.0f);  // not in the region
}

TEST(PlaneDepth, NearestPlaneFirstOnTiesAndWithinTheAssignThreshold) {
  // Two planes z = 1 and z = 1 (equal distances: the first wins) and z = 3; products t = p · n.
  const double x[] = {0.0, 0.0, 0.0};
  const double y[] = {0.0, 0.0, 0.0};
  const double depth[] = {1.05, 2.95, 2.0};
  const int64_t flat[] = {0, 1, 2};
  const double planes[] = {0, 0, 1, -1.0,   //
                           0, 0, 1, -1.0,   //
                           0, 0, 1, -3.0};  // (p · n = z for every plane)
  const double products[] = {1.05, 1.05, 1.05, 2.95, 2.95, 2.95, 2.0, 2.0, 2.0};
  float out[3] = {0, 0, 0};
  EXPECT_EQ(MoveOntoPlanes({x, y, depth, flat, 3}, planes, 3, products, {0.08, 0.5}, out, 3), 2);
  EXPECT_EQ(out[0], 1.0f);  // 0.05 from the first plane
  EXPECT_EQ(out[1], 3.0f);  // 0.05 from the third
  EXPECT_EQ(out[2], 0.0f);  // 1.0 from both z = 1 and z = 3: beyond the threshold
}

TEST(PlaneDepth, NanDistancesAndZeroDenominatorsMoveNothing) {
  const double x[] = {0.0, 0.0, 0.0};
  const double y[] = {0.0, 0.0, 0.0};
  const double depth[] = {1.0, 1.0, 1.0};
  const int64_t flat[] = {0, 1, 2};
  const double planes[] = {0, 0, 1, -1.0, 0, 0, 1, -1.0};
  const double products[] = {NAN, 1.0, 1.0, NAN, 1.0, 1.0};
  float out[3] = {7, 7, 7};
  // a NaN distance: np.minimum's NaN fails the threshold (and np.argmin picks it)
  EXPECT_EQ(MoveOntoPlanes({x, y, depth, flat, 3}, planes, 2, products, {0.08, 0.5}, out, 3), 1);
  EXPECT_EQ(out[0], 7.0f);
  EXPECT_EQ(out[1], 7.0f);
  EXPECT_EQ(out[2], 1.0f);
  // n = (1, 0, 0) and x = 0: 1 / 0 = inf, and 0 / 0 = NaN, neither finite
  const double vertical[] = {1, 0, 0, -1.0};
  const double through[] = {1, 0, 0, 0.0};
  EXPECT_EQ(MoveOntoPlanes({x, y, depth, flat, 3}, vertical, 1, nullptr, {0.08, 1e300}, out, 3), 0);
  EXPECT_EQ(MoveOntoPlanes({x, y, depth, flat, 3}, through, 1, nullptr, {0.08, 1e300}, out, 3), 0);
}

TEST(PlaneDepth, DepthsBeyondFloat32RoundAsNumpy) {
  const double zero[] = {0.0};
  const double depth[] = {3.0e38};
  const int64_t flat[] = {0};
  const double max = 3.4028234663852886e38;  // FLT_MAX
  float out[1];
  for (const auto& [z, expected] : {std::pair{max, max}, std::pair{max + 0x1p102, max},
                                    std::pair{max + 0x1p103, static_cast<double>(INFINITY)}}) {
    const double plane[] = {0, 0, 1, -z};
    out[0] = 0;
    MoveOntoPlanes({zero, zero, depth, flat, 1}, plane, 1, nullptr, {0.08, 1.0}, out, 1);
    EXPECT_EQ(out[0], static_cast<float>(expected)) << z;
  }
}

TEST(PlaneDepth, RejectsIndicesOutsideTheImageBeforeWriting) {
  const double x[] = {0.0, 0.0};
  const double depth[] = {1.0, 1.0};
  const int64_t flat[] = {0, 2};
  const double plane[] = {0, 0, 1, -1.0};
  float out[2] = {5, 5};
  try {
    MoveOntoPlanes({x, x, depth, flat, 2}, plane, 1, nullptr, {0.08, 1.0}, out, 2);
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "flat");
    EXPECT_NE(std::string(e.what()).find("index 2 at 1"), std::string::npos);
  }
  EXPECT_EQ(out[0], 5.0f);  // nothing written
  EXPECT_THROW(MoveOntoPlanes({x, x, depth, flat, 1}, plane, 0, nullptr, {0.08, 1.0}, out, 2),
               RasterError);
}

TEST(PlaneDepth, ProductsFormedWhenNotGiven) {
  // two planes z = 1 and z = 2 seen along the optical axis from z = 1.2 and 1.9: the nearest
  // one taken with the products formed here as with the table given (t = z, exactly)
  const double x[] = {0.0, 0.0};
  const double depth[] = {1.2, 1.9};
  const int64_t flat[] = {0, 1};
  const double planes[] = {0, 0, 1, -1.0, 0, 0, 1, -2.0};
  const double products[] = {1.2, 1.2, 1.9, 1.9};
  float formed[2] = {0, 0}, given[2] = {0, 0};
  EXPECT_EQ(MoveOntoPlanes({x, x, depth, flat, 2}, planes, 2, nullptr, {0.5, 1.0}, formed, 2), 2);
  EXPECT_EQ(MoveOntoPlanes({x, x, depth, flat, 2}, planes, 2, products, {0.5, 1.0}, given, 2), 2);
  EXPECT_EQ(formed[0], 1.0f);
  EXPECT_EQ(formed[1], 2.0f);
  EXPECT_EQ(formed[0], given[0]);
  EXPECT_EQ(formed[1], given[1]);
}

TEST(DepthNormals, FlatWallFacingTheCameraWithSignedZeros) {
  // z = 2 everywhere on a 4 × 5 image, fx = fy = 1, cx = cy = 0: p = (2u, 2v, 2); step 1:
  // d_u = (4, 0, 0), d_v = (0, 4, 0), cross = (0·0 − 0·4, 0·0 − 4·0, 4·4 − 0·0) = (0, 0, 16),
  // normalised (0, 0, 1), facing away (n · p = 2 > 0): negated, (−0, −0, −1), as np.negative.
  std::vector<float> depth(20, 2.0f);
  std::vector<double> points(60), cross(60);
  bool valid[20], ok[20];
  DepthCross<double>({depth.data(), 4, 5}, {1.0, 1.0, 0.0, 0.0}, 1,
                     {points.data(), valid, ok, cross.data()});
  EXPECT_EQ(points[3 * 7], 4.0);  // (u 2, v 1): x = 2 · 2
  EXPECT_EQ(points[3 * 7 + 1], 2.0);
  EXPECT_TRUE(valid[0] && valid[19]);
  // the interior: u 1..3, v 1..2
  EXPECT_FALSE(ok[0] || ok[5] || ok[9] || ok[14]);
  EXPECT_TRUE(ok[6] && ok[7] && ok[8] && ok[11] && ok[12] && ok[13]);
  EXPECT_EQ(cross[3 * 7 + 2], 16.0);
  OrientNormals(20, points.data(), cross.data(), ok);
  EXPECT_EQ(cross[3 * 7 + 2], -1.0);
  EXPECT_EQ(cross[3 * 7], 0.0);
  EXPECT_TRUE(std::signbit(cross[3 * 7]));   // −0, as numpy's negation of +0
  EXPECT_FALSE(std::signbit(cross[3 * 0]));  // no normal: +0
}

TEST(DepthNormals, DepthJumpsAndMissingNeighboursHaveNoNormal) {
  // 3 × 5, step 1: the interior is row 1, columns 1..3.
  std::vector<float> depth(15, 1.0f);
  depth[1 * 5 + 4] = 2.0f;  // right neighbour of (3, 1): |2 − 1| = 1 >= 2 (0.05 + 0.05)
  depth[0 * 5 + 1] = 0.0f;  // upper neighbour of (1, 1) has no depth
  std::vector<double> points(45);
  std::vector<float> cross(45, 7.0f);
  bool valid[15], ok[15];
  DepthCross<float>({depth.data(), 3, 5}, {1.0, 1.0, 2.0, 1.0}, 1,
                    {points.data(), valid, ok, cross.data()});
  EXPECT_FALSE(valid[1]);
  EXPECT_FALSE(ok[6]);
  EXPECT_TRUE(ok[7]);
  EXPECT_FALSE(ok[8]);
  EXPECT_EQ(cross[3 * 8], 0.0f);  // cleared, not left at 7
  EXPECT_THROW(DepthCross<float>({depth.data(), 3, 5}, {1.0, 1.0, 2.0, 1.0}, 0,
                                 {points.data(), valid, ok, cross.data()}),
               RasterError);
}

TEST(DepthNormals, JumpOffsetWidensTheJumpTest) {
  // 3 × 5, step 1; at (2, 1) the neighbours' depths differ by 0.35 m: a jump for the segmenter's
  // 2 (0.05 · 2 + 0.05) = 0.3, none for the orientation check's 2 (0.05 · 2 + 0.1) = 0.4.
  std::vector<float> depth(15, 2.0f);
  for (int v = 0; v < 3; ++v) depth[v * 5 + 3] = 2.35f;
  std::vector<double> points(45), cross(45);
  bool valid[15], ok[15];
  DepthCross<double>({depth.data(), 3, 5}, {1.0, 1.0, 0.0, 0.0}, 1,
                     {points.data(), valid, ok, cross.data()});
  EXPECT_TRUE(ok[6]);
  EXPECT_FALSE(ok[7]);
  DepthCross<double>({depth.data(), 3, 5}, {1.0, 1.0, 0.0, 0.0}, 1,
                     {points.data(), valid, ok, cross.data()}, 0.1);
  EXPECT_TRUE(ok[6]);
  EXPECT_TRUE(ok[7]);
}

// Grey levels by hand: 0.299 r + 0.587 g + 0.114 b rounded to nearest, halves to even (rint).
TEST(Gray, Bt601LumaRoundedAsRint) {
  const std::vector<uint8_t> rgb = {
      0,   0,   0,    // 0
      255, 255, 255,  // 0.299 + 0.587 + 0.114 = 1 (to rounding): 255
      255, 0,   0,    // 76.245 -> 76
      0,   255, 0,    // 149.685 -> 150
      0,   0,   255,  // 29.07 -> 29
      1,   1,   0,    // 0.886 -> 1
      0,   0,   4,    // 0.456 -> 0
      5,   0,   0,    // 1.495 -> 1
  };
  std::vector<uint8_t> gray(rgb.size() / 3, 7);
  RgbToGray(rgb.data(), static_cast<int64_t>(gray.size()), gray.data());
  EXPECT_EQ(gray, (std::vector<uint8_t>{0, 255, 76, 150, 29, 1, 0, 1}));
}

// Each PNG filter on 2 px of 2 bytes (worked by hand from the specification, mod 256).
TEST(PngRows, EveryFilterByHand) {
  const std::vector<uint8_t> filtered = {
      1, 10, 20, 5, 250,  // Sub:     10 20 | 10+5 20+250        -> 10 20 15 14
      3, 1, 2, 3, 4,      // Average: 1+5 2+10 | 3+(6+15)/2 4+(12+14)/2 -> 6 12 13 17
      4, 100, 0, 7, 255,  // Paeth:   first pixel takes b (Up); then a = 106, b = 13,
                          //          c = 6: p = 113 nearest a; a = 12, b = 17, c = 12: b
      2, 1, 1, 1, 1,      // Up
      0, 9, 8, 7, 6,      // None
  };
  std::vector<uint8_t> out(5 * 4, 0);
  UnfilterPngRows(filtered.data(), 5, 4, 2, out.data());
  EXPECT_EQ(out, (std::vector<uint8_t>{10,  20, 15,  14, 6,   12, 13, 17, 106, 12,
                                       113, 16, 107, 13, 114, 17, 9,  8,  7,   6}));
}

// In the first row the bytes above are 0: Up copies, Average halves the left byte, Paeth is
// Sub.
TEST(PngRows, FirstRowHasZerosAbove) {
  for (const uint8_t type : {2, 3, 4}) {
    const std::vector<uint8_t> filtered = {type, 7, 200, 100};
    std::vector<uint8_t> out(3, 0);
    UnfilterPngRows(filtered.data(), 1, 3, 1, out.data());
    const std::vector<uint8_t> expected =
        type == 2   ? std::vector<uint8_t>{7, 200, 100}
        : type == 3 ? std::vector<uint8_t>{7, 203, 201}  // 200 + 7/2, 100 + 203/2
                    : std::vector<uint8_t>{7, 207, 51};  // 200 + 7, 100 + 207 (mod 256)
    EXPECT_EQ(out, expected) << "filter " << int{type};
  }
}

// Paeth's ties: |p - b| = |p - c| < |p - a| takes b, |p - a| = |p - c| < |p - b| takes a.
TEST(PngRows, PaethTies) {
  std::vector<uint8_t> out(4, 0);
  const std::vector<uint8_t> b_wins = {0, 10, 8, 4, 1, 0};  // a = 11, b = 8, c = 10
  UnfilterPngRows(b_wins.data(), 2, 2, 1, out.data());
  EXPECT_EQ(out, (std::vector<uint8_t>{10, 8, 11, 8}));
  const std::vector<uint8_t> a_wins = {0, 10, 11, 4, 254, 0};  // a = 8, b = 11, c = 10
  UnfilterPngRows(a_wins.data(), 2, 2, 1, out.data());
  EXPECT_EQ(out, (std::vector<uint8_t>{10, 11, 8, 8}));
}

// A zlib stream of one stored (uncompressed) deflate block around `data`, Adler-32 at the end.
std::vector<uint8_t> StoredZlib(const std::vector<uint8_t>& data) {
  const auto n = static_cast<uint16_t>(data.size());
  std::vector<uint8_t> z = {0x78,
                            0x01,
                            0x01,
                            static_cast<uint8_t>(n & 0xFF),
                            static_cast<uint8_t>(n >> 8),
                            static_cast<uint8_t>(~n & 0xFF),
                            static_cast<uint8_t>((~n >> 8) & 0xFF)};
  for (const uint8_t byte : data) z.push_back(byte);
  uint32_t a = 1, b = 0;
  for (const uint8_t byte : data) {
    a = (a + byte) % 65521;
    b = (b + a) % 65521;
  }
  const uint32_t adler = (b << 16) | a;
  for (const int shift : {24, 16, 8, 0}) z.push_back(static_cast<uint8_t>(adler >> shift));
  return z;
}

TEST(PngRows, DecodeInflatesThenUnfilters) {
  const std::vector<uint8_t> filtered = {1, 10, 20, 5, 250, 2, 1, 1, 1, 1};
  const std::vector<uint8_t> stream = StoredZlib(filtered);
  std::vector<uint8_t> out(8, 0);
  DecodePngRows(stream.data(), static_cast<int64_t>(stream.size()), 2, 4, 2, out.data());
  EXPECT_EQ(out, (std::vector<uint8_t>{10, 20, 15, 14, 11, 21, 16, 15}));

  const auto expect_stream_error = [&](const std::vector<uint8_t>& bad, const char* what) {
    try {
      DecodePngRows(bad.data(), static_cast<int64_t>(bad.size()), 2, 4, 2, out.data());
      FAIL() << what << " accepted";
    } catch (const RasterError& e) {
      EXPECT_EQ(e.field(), "stream") << what;
    }
  };
  std::vector<uint8_t> bad_sum = stream;
  bad_sum.back() ^= 1;
  expect_stream_error(bad_sum, "a wrong Adler-32");
  std::vector<uint8_t> trailing = stream;
  trailing.push_back(0);
  expect_stream_error(trailing, "a byte after the stream");
  expect_stream_error(StoredZlib({1, 10, 20, 5, 250, 2, 1, 1, 1}), "a byte short");
  expect_stream_error(StoredZlib({1, 10, 20, 5, 250, 2, 1, 1, 1, 1, 0}), "a byte too many");
  expect_stream_error({0x78, 0x01, 0x07}, "a bad block type");
  EXPECT_THROW(
      DecodePngRows(stream.data(), static_cast<int64_t>(stream.size()), 0, 4, 2, out.data()),
      RasterError);
}

TEST(PngRows, BadInput) {
  const std::vector<uint8_t> filtered = {0, 1, 2, 5, 3, 4};
  std::vector<uint8_t> out(4, 0);
  try {
    UnfilterPngRows(filtered.data(), 2, 2, 1, out.data());
    FAIL() << "filter type 5 accepted";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "filtered");
    EXPECT_NE(std::string(e.what()).find("row 1 has filter type 5"), std::string::npos);
  }
  EXPECT_THROW(UnfilterPngRows(filtered.data(), 2, 2, 0, out.data()), RasterError);
  EXPECT_THROW(UnfilterPngRows(filtered.data(), 2, 2, 9, out.data()), RasterError);
}

// Brute force over every pixel: (d², index) ascending, d² = dx² + dy² rounded as written.
TEST(NearestPixels, MatchesBruteForceWithTiesByIndex) {
  // a 9 × 7 image with pixels in a fixed pattern (rows listed left to right, as np.nonzero)
  std::vector<int64_t> row_start = {0}, cols;
  std::vector<std::pair<int64_t, int64_t>> pixels;  // (col, row) by index
  for (int64_t v = 0; v < 7; ++v) {
    for (int64_t u = 0; u < 9; ++u) {
      if ((u * 7 + v * 3) % 5 == 0 || (u == 4 && v == 3)) {
        cols.push_back(u);
        pixels.emplace_back(u, v);
      }
    }
    row_start.push_back(static_cast<int64_t>(cols.size()));
  }
  const int64_t n = static_cast<int64_t>(cols.size());
  // queries between pixels (exact ties: 4.5 is as far from columns 4 and 5), on a pixel, and
  // outside the image
  const std::vector<double> queries = {4.5,  3.0,  4.0,  3.0, 0.25, 6.75,
                                       -3.0, -2.0, 12.5, 9.0, 2.0,  2.5};
  const int num_queries = static_cast<int>(queries.size() / 2);
  for (const int k : {1, 3, 7, static_cast<int>(n)}) {
    std::vector<int64_t> got(static_cast<size_t>(num_queries) * k, -1);
    NearestPixels(row_start.data(), 7, cols.data(), n, queries.data(), num_queries, k, got.data());
    for (int q = 0; q < num_queries; ++q) {
      std::vector<std::pair<double, int64_t>> all;
      for (int64_t i = 0; i < n; ++i) {
        const double dx = queries[2 * q] - static_cast<double>(pixels[i].first);
        const double dy = queries[2 * q + 1] - static_cast<double>(pixels[i].second);
        all.emplace_back(dx * dx + dy * dy, i);
      }
      std::sort(all.begin(), all.end());
      for (int j = 0; j < k; ++j) {
        EXPECT_EQ(got[q * k + j], all[j].second) << "k " << k << " query " << q << " rank " << j;
      }
    }
  }
}

TEST(NearestPixels, BadInput) {
  const std::vector<int64_t> row_start = {0, 2, 3}, cols = {1, 4, 0};
  const std::vector<double> query = {1.0, 1.0};
  std::vector<int64_t> out(3);
  const auto field = [&](const std::vector<int64_t>& starts, const std::vector<int64_t>& c,
                         const std::vector<double>& q, int k) {
    try {
      NearestPixels(starts.data(), static_cast<int64_t>(starts.size()) - 1, c.data(),
                    static_cast<int64_t>(c.size()), q.data(), 1, k, out.data());
    } catch (const RasterError& e) {
      return e.field();
    }
    return std::string("none");
  };
  EXPECT_EQ(field(row_start, cols, query, 3), "none");
  EXPECT_EQ(field(row_start, cols, query, 0), "k");
  EXPECT_EQ(field(row_start, cols, query, 4), "k");
  EXPECT_EQ(field({0, 2, 2}, cols, query, 1), "row_start");
  EXPECT_EQ(field({0, 3, 2}, cols, query, 1), "row_start");
  EXPECT_EQ(field(row_start, {4, 1, 0}, query, 1), "cols");
  EXPECT_EQ(field(row_start, cols, {std::nan(""), 1.0}, 1), "queries");
}

// One pixel of region 2 at (row 1, col 3) in a 4 × 5 image: the pixels within 1 row and column
// of it are near, with the entries' rows ascending or not, and a band of rows wider than the
// region changes nothing.
TEST(NearRegion, WindowOfTheRegion) {
  std::vector<int32_t> ids(20, -1);
  ids[1 * 5 + 3] = 2;
  ids[3 * 5 + 0] = 1;
  const ImageRef<const int32_t> image{ids.data(), 4, 5};
  const std::vector<int64_t> at = {0, 2, 4, 7, 9, 12, 14, 15, 17, 19};
  for (const bool ascending : {true, false}) {
    for (const auto& [top, stop] : {std::pair<int64_t, int64_t>{1, 2}, {0, 4}}) {
      // entries (0,0) (0,2) (0,4) (1,2) (1,4) (2,2) (2,4) (3,0) (3,2) (3,4)
      EXPECT_EQ(NearRegion(image, 2, 1, at.data(), 10, ascending, top, stop),
                (std::vector<int64_t>{1, 2, 3, 4, 5, 6}));
    }
  }
  EXPECT_EQ(NearRegion(image, 2, 0, at.data(), 10, true, 1, 2), (std::vector<int64_t>{}));
  EXPECT_EQ(NearRegion(image, 1, 2, at.data(), 10, true, 3, 4),
            (std::vector<int64_t>{3, 5, 7, 8}));  // (1,2) (2,2) (3,0) (3,2)
  const std::vector<int64_t> outside = {3, 20};
  EXPECT_THROW(NearRegion(image, 2, 1, outside.data(), 2, false, 0, 4), RasterError);
  EXPECT_THROW(NearRegion(image, 2, -1, at.data(), 10, true, 0, 4), RasterError);
}

// Brute force: (d², index) ascending, d² = ((dx² + dy²) + dz²) as written. Lattice points (many
// equal distances), a far cluster (the all-points fallback), cells far smaller and larger than
// the spacing.
TEST(NearestPoints, MatchesBruteForceWithTiesByIndex) {
  std::vector<double> points;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 3; ++j) {
      for (int l = 0; l < 3; ++l) {
        points.insert(points.end(), {0.5 * i, 0.5 * j - 0.25, 0.5 * l + 0.1});
      }
    }
  }
  points.insert(points.end(), {40.0, -40.0, 7.0, 40.5, -40.0, 7.0});  // far away
  const int64_t n = static_cast<int64_t>(points.size() / 3);
  const std::vector<double> queries = {0.5, 0.25, 0.6, 0.3, 0.1, 0.35,  40.2, -39.9,
                                       7.0, -3.0, 2.0, 1.0, 0.5, -0.25, 0.1};
  const int64_t num_queries = static_cast<int64_t>(queries.size() / 3);
  for (const double cell : {0.01, 0.3, 0.5, 2.0, 100.0}) {
    for (const int k : {1, 5, 27, static_cast<int>(n)}) {
      std::vector<int64_t> got(static_cast<size_t>(num_queries * k), -1);
      NearestPoints(points.data(), n, queries.data(), num_queries, k, cell, got.data());
      for (int64_t q = 0; q < num_queries; ++q) {
        std::vector<std::pair<double, int64_t>> all;
        for (int64_t i = 0; i < n; ++i) {
          const double d0 = queries[3 * q] - points[3 * i];
          const double d1 = queries[3 * q + 1] - points[3 * i + 1];
          const double d2 = queries[3 * q + 2] - points[3 * i + 2];
          double d = 0.0;
          d += d0 * d0;
          d += d1 * d1;
          d += d2 * d2;
          all.emplace_back(d, i);
        }
        std::sort(all.begin(), all.end());
        for (int j = 0; j < k; ++j) {
          ASSERT_EQ(got[q * k + j], all[j].second)
              << "cell " << cell << " k " << k << " query " << q << " rank " << j;
        }
      }
    }
  }
}

TEST(NearestPoints, BadInput) {
  const std::vector<double> points = {0, 0, 0, 1, 0, 0}, query = {0.2, 0, 0};
  std::vector<int64_t> out(2);
  const auto field = [&](const std::vector<double>& p, const std::vector<double>& q, int k,
                         double cell) {
    try {
      NearestPoints(p.data(), static_cast<int64_t>(p.size() / 3), q.data(), 1, k, cell, out.data());
    } catch (const RasterError& e) {
      return e.field();
    }
    return std::string("none");
  };
  EXPECT_EQ(field(points, query, 2, 0.5), "none");
  EXPECT_EQ(out, (std::vector<int64_t>{0, 1}));
  EXPECT_EQ(field(points, query, 0, 0.5), "k");
  EXPECT_EQ(field(points, query, 3, 0.5), "k");
  EXPECT_EQ(field(points, query, 1, 0.0), "cell");
  EXPECT_EQ(field(points, query, 1, std::nan("")), "cell");
  EXPECT_EQ(field({0, 0, std::nan(""), 1, 0, 0}, query, 1, 0.5), "points");
  EXPECT_EQ(field(points, {0, 1e300, 0}, 1, 0.5), "queries");
}

TEST(PlaneScores, StrictTestsAndAddedCounts) {
  // 3 points × 2 hypotheses along x and y, so that t_ij is the point's coordinate j:
  // |t + d| < thr strictly (point 1 sits exactly at the threshold of hypothesis 0), |a| > cos_n
  // strictly, a NaN coordinate makes every product NaN and fails both tests.
  const double points[] = {0.1, 0.0, 0.0, 0.5, 2.0, 0.0, std::nan(""), 0.2, 0.0};
  const double normals[] = {0.9, 0.9, 0.0, 0.9, 0.5, 0.0, 0.9, 0.9, 0.0};
  const double planes[] = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0};
  const double offsets[] = {0.0, -0.1};
  const double thresholds[] = {0.2, 0.5, 0.3};
  int64_t score[] = {10, 20};
  AddPlaneScores(points, nullptr, planes, offsets, thresholds, 3, 2, 0.0, score);
  EXPECT_EQ(score[0], 11);  // 0.1 < 0.2; 0.5 < 0.5 no; NaN no
  EXPECT_EQ(score[1], 21);  // 0.1 < 0.2; 1.9 < 0.5 no; NaN no
  AddPlaneScores(points, normals, planes, offsets, thresholds, 3, 2, 0.5, score);
  EXPECT_EQ(score[0], 12);
  EXPECT_EQ(score[1], 22);  // row 1's agreement is 0.5, not > 0.5 (and its distance fails)
}

TEST(PlaneScores, ProductsAreFusedMultiplyAdds) {
  // p · h with p0 h0 + p1 h1 cancelling: the fused form keeps the low bits that a rounded
  // product loses, and the threshold sits between the two results.
  const double e = std::ldexp(1.0, -30);
  const double points[] = {1.0 + e, 1.0 - e, 0.0, 1.0 + e, 1.0 - e, 0.0};
  const double planes[] = {1.0 + e, -(1.0 + e), 0.0, 1.0 + e, -(1.0 + e), 0.0};
  const double offsets[] = {0.0, 0.0};
  const double fused = std::fma(1.0 - e, -(1.0 + e), (1.0 + e) * (1.0 + e));
  const double rounded = (1.0 + e) * (1.0 + e) + (1.0 - e) * -(1.0 + e);
  ASSERT_NE(fused, rounded);
  const double thresholds[] = {std::max(std::fabs(fused), std::fabs(rounded)),
                               std::min(std::fabs(fused), std::fabs(rounded))};
  int64_t score[] = {0, 0};
  AddPlaneScores(points, nullptr, planes, offsets, thresholds, 2, 2, 0.0, score);
  // point 0 counts where |t| < max(|fused|, |rounded|): true for the smaller one only
  const int64_t want = std::fabs(fused) < thresholds[0] ? 1 : 0;
  EXPECT_EQ(score[0], want);
  EXPECT_EQ(score[1], want);
}

TEST(ComponentPixels, GroupedByLabelRowMajorInside) {
  // 3 × 4 labels; label 3 unused; the background (0) left out.
  const int32_t labels[] = {0, 2, 2, 1,  //
                            1, 0, 2, 1,  //
                            4, 4, 0, 1};
  int64_t starts[6];
  ASSERT_EQ(ComponentStarts(labels, 12, 5, starts), 9);
  const std::vector<int64_t> expected_starts = {0, 0, 4, 7, 7, 9};
  EXPECT_EQ(std::vector<int64_t>(starts, starts + 6), expected_starts);
  std::vector<int64_t> pixels(9);
  ComponentPixels(labels, 12, 5, starts, pixels.data());
  const std::vector<int64_t> expected = {3, 4, 7, 11, 1, 2, 6, 8, 9};
  EXPECT_EQ(pixels, expected);
  const int32_t bad[] = {0, 5};
  try {
    ComponentStarts(bad, 2, 5, starts);
    FAIL() << "no exception";
  } catch (const RasterError& e) {
    EXPECT_EQ(e.field(), "labels");
  }
}

TEST(VoxelNormals, MeansPerVoxelInKeyOrderWithinRange) {
  // two returns in voxel (1, 0, 0), one in (0, 0, 0), one too near, one too far (voxel 1 m)
  const std::vector<double> points = {1.25, 0.5, 0.5, 0.5, 0.5, 0.5, 1.75, 0.25,
                                      0.75, 0.1, 0.0, 0.0, 9.0, 0.0, 0.0};
  const ScanVoxels v = VoxelMeans(points.data(), 5, 0.5, 5.0, 1.0);
  EXPECT_EQ(v.num_kept, 3);
  ASSERT_EQ(v.means.size(), 6u);
  const std::vector<double> want = {
      0.5, 0.5, 0.5, (1.25 + 1.75) / 2, (0.5 + 0.25) / 2, (0.5 + 0.75) / 2};
  for (size_t i = 0; i < want.size(); ++i) EXPECT_EQ(v.means[i], want[i]) << i;
  EXPECT_THROW(VoxelMeans(points.data(), 5, 0.0, 5.0, 0.0), RasterError);
  const double far[3] = {1e30, 0.0, 0.0};
  EXPECT_THROW(VoxelMeans(far, 1, 0.0, INFINITY, 0.1), RasterError);
}

TEST(VoxelNormals, PlaneLineAndBadIndices) {
  // a tilted plane z = 0.5 x sampled on a grid, and a line along x
  std::vector<double> cloud;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) cloud.insert(cloud.end(), {1.0 * i, 1.0 * j, 0.5 * i});
  }
  for (int i = 0; i < 4; ++i) cloud.insert(cloud.end(), {10.0 + i, 0.0, 0.0});
  std::vector<int64_t> neighbours;
  for (int64_t i = 0; i < 16; ++i) neighbours.push_back(i);
  for (int64_t i = 16; i < 20; ++i) neighbours.push_back(i);
  neighbours.resize(32, 16);  // the line's row: its 4 points, then the first again
  double normals[6];
  bool planar[2];
  PcaNormals(cloud.data(), 20, neighbours.data(), 2, 16, 0.1, 0.05, normals, planar);
  const double s = 1.0 / std::sqrt(1.25);  // (-0.5, 0, 1) / |.|
  EXPECT_NEAR(std::fabs(normals[0]), 0.5 * s, 1e-12);
  EXPECT_NEAR(normals[1], 0.0, 1e-12);
  EXPECT_NEAR(std::fabs(normals[2]), s, 1e-12);
  EXPECT_LT(normals[0] * normals[2], 0.0);
  EXPECT_TRUE(planar[0]);
  EXPECT_FALSE(planar[1]);  // a line: λ1 = 0 < min_spread λ2
  neighbours[3] = 20;
  EXPECT_THROW(PcaNormals(cloud.data(), 20, neighbours.data(), 2, 16, 0.1, 0.05, normals, planar),
               RasterError);
  EXPECT_THROW(PcaNormals(cloud.data(), 20, neighbours.data(), 2, 0, 0.1, 0.05, normals, planar),
               RasterError);
}

TEST(RangeNoise, RingOfAlternatingRangesAndTooFewTriples) {
  // one ring at elevation 0, 0.1° steps, ranges 5 + e and 5 − e alternating: every second
  // difference is ±4e, so σ = 4e / (0.6745 √6)
  const double e = 0.01;
  std::vector<double> points;
  for (int k = 0; k < 500; ++k) {
    const double a = (0.1 * k - 25.0) * M_PI / 180.0, r = 5.0 + (k % 2 ? -e : e);
    points.insert(points.end(), {r * std::cos(a), r * std::sin(a), 0.0});
  }
  const std::optional<double> sigma = ScanRangeNoise(points.data(), 500, 0.5, 0.5);
  ASSERT_TRUE(sigma.has_value());
  EXPECT_NEAR(*sigma, 4 * e / (0.6745 * std::sqrt(6.0)), 1e-9);
  EXPECT_FALSE(ScanRangeNoise(points.data(), 90, 0.5, 0.5).has_value());    // 88 triples
  EXPECT_FALSE(ScanRangeNoise(points.data(), 500, 0.5, 0.05).has_value());  // steps too wide
  EXPECT_THROW(ScanRangeNoise(points.data(), 500, 0.0, 0.5), RasterError);
}

}  // namespace
}  // namespace bimcap::raster
