// The completion's raster (bimcap/raster/): the expected images were drawn by OpenCV 5.0's
// cv2.fillConvexPoly(image, corners, id, cv2.LINE_8, 4) (tests/test_frontend_speed.py compares
// the two on random and real triangles); the affine values are computed by hand.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/piecewise_affine.h"

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

}  // namespace
}  // namespace bimcap::raster
