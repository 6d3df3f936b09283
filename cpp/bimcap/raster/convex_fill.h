// OpenCV's cv::fillConvexPoly (LINE_8, fixed-point vertices), reproduced pixel for pixel, and the
// triangle-id image of the linear depth completion built from it.
//
// bimcap.fusion.completion.complete_linear drew each kept Delaunay triangle with
// cv2.fillConvexPoly(tri_id, corners, id, LINE_8, shift=4); the depth maps of every run so far
// depend on exactly which pixels that call writes, so this is not a generic rasteriser but the
// same integer algorithm (imgproc/src/drawing.cpp: FillConvexPoly, Line2, clipLine), written
// anew for one int32 channel:
//
//   vertices p_i in 1/2^shift px (an int point (x, y) is the pixel centre (x, y) / 2^shift);
//   internally in 16.16 fixed point:  P_i = p_i · 2^(16 − shift),  ONE = 2^16.
//
// 1. Outline: every edge P_{i−1} → P_i (P_{−1} = P_{n−1}) is drawn by an 8-connected DDA
//    (Line2): clipped to [0, W·ONE − 1] × [0, H·ONE − 1], stepping one pixel along the major
//    axis from the lesser end, the minor coordinate advancing by round-toward-zero
//    (d_minor · ONE) / (|d_major| | 1); pixel = (coordinate + ONE/2) >> 16, plus the far end.
// 2. Interior: scan lines y = round(y_min) … min(round(y_max), H − 1), round(a) = (a + 2^(shift−1))
//    >> shift; two edges walk from the top vertex, one in vertex order and one against it; each
//    edge starts at its upper vertex's x with the slope ((x_e − x_s)·2 + Δy) / (2 Δy) (integer
//    division, Δy in rows) and is advanced once per row; the row is filled from
//    (x_left + ONE/2) >> 16 to (x_right + ONE/2) >> 16, clipped to the image.
//
// Pixels written by a later polygon overwrite earlier ones, as repeated cv2 calls do.
#ifndef BIMCAP_RASTER_CONVEX_FILL_H_
#define BIMCAP_RASTER_CONVEX_FILL_H_

#include <cstdint>

#include "bimcap/problem.h"
#include "bimcap/raster/image.h"

namespace bimcap::raster {

// The most fractional bits of a vertex coordinate (cv::fillConvexPoly's `shift`); the least is 1
// (shift 0 makes OpenCV draw the outline with another line algorithm, not reproduced here).
constexpr int kMaxShift = 16;

// The largest |coordinate| of a vertex and the largest image side, in px: in 16.16 fixed point
// the products of the outline's clipping then stay inside int64 (OpenCV's own code overflows
// beyond about 2^15 px).
constexpr int64_t kMaxCoordinatePx = int64_t{1} << 14;

// A bad argument of a raster function (shape, shift, index); `field()` names it.
class RasterError : public InputError {
 public:
  using InputError::InputError;
};

// Throws RasterError (`field`) at the first of index[begin, end) outside [0, size): raveled pixel
// indices of an image of `size` pixels.
void CheckPixelIndices(const int64_t* index, int64_t begin, int64_t end, int64_t size,
                       const char* field);

// cv::fillConvexPoly(image, vertices, value, LINE_8, shift) for a convex polygon of `count`
// vertices given as x0, y0, x1, y1, … (in 1/2^shift px, the same int32 points cv2 takes).
// Polygons with fewer than 3 vertices draw their outline only, as OpenCV does; `count` = 0 draws
// nothing. Throws RasterError (and draws nothing) for a shift outside [1, 16], an image side or
// a vertex coordinate beyond kMaxCoordinatePx px.
void FillConvexPolygon(const ImageRef<int32_t>& image, const int32_t* vertices, int count,
                       int32_t value, int shift);

// The triangle-id image: for t = 0 … T − 1 in order, triangle t (corners[6t … 6t + 5] = x0, y0,
// x1, y1, x2, y2 in 1/2^shift px) is filled with ids[t] by FillConvexPolygon; `image` is not
// cleared first. The result equals T calls of cv2.fillConvexPoly(image, corners[t], ids[t],
// cv2.LINE_8, shift). Every triangle is checked before any is drawn (RasterError "corners"
// naming the first bad one, or "shift" / "image").
void FillTriangleIds(const ImageRef<int32_t>& image, const int32_t* corners, const int32_t* ids,
                     int64_t count, int shift);

// The pixels whose centre triangle t contains, set to ids[t] (others untouched): the owner pass of
// the linear completion (bimcap.fusion.completion.PixelOwner.CENTRE). For corners a, b, c in
// 1/2^shift px, ordered so that the doubled area (b − a) × (c − a) is positive, and a pixel centre
// p = (u, v) · 2^shift, each directed edge s → t gives, in exact int64 arithmetic,
//
//   E(p) = (t − s) × (p − s) = (t_x − s_x)(p_y − s_y) − (t_y − s_y)(p_x − s_x),
//
// and p is inside when for every edge E(p) > 0, or E(p) = 0 and d = t − s has d_y < 0, or d_y = 0
// and d_x > 0 (the top-left rule: p read as p + (ε₁, ε₂), 0 < ε₂ ≪ ε₁ ≪ 1). Two triangles that
// share an edge run it in opposite directions, so a centre on it, or on a vertex, belongs to
// exactly one triangle of a triangulation: the result does not depend on the order of the
// triangles. Triangles of zero area contain nothing. Every triangle is checked before any is
// drawn (RasterError "corners", "shift" or "image", as FillTriangleIds).
void FillContainingTriangleIds(const ImageRef<int32_t>& image, const int32_t* corners,
                               const int32_t* ids, int64_t count, int shift);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_CONVEX_FILL_H_
