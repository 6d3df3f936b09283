// Points and normals of a z-depth map (the geometric segmenter's first step,
// bimcap.segmentation.geometric._points_and_normals), in numpy's arithmetic bit for bit.
//
//   z = float64(depth),  p(u, v) = (x_u z, y_v z, z),  x_u = (u − cx) / fx,  y_v = (v − cy) / fy
//   valid = z > 0
//   interior (s <= u < w − s, s <= v < h − s, s = step): ok where the pixel and its four
//   neighbours at ±s have depth and |z(u+s) − z(u−s)| < 2 (0.05 z + j), likewise along v
//   (j = jump_offset_m: the segmenter's 0.05, the label orientation check's coarse normals' 0.1,
//   bimcap.frontend.semantic_map._coarse_normals)
//   d_u = p(u+s, v) − p(u−s, v),  d_v = p(u, v+s) − p(u, v−s)   (component by component)
//   cross = (d_u1 d_v2 − d_u2 d_v1,  d_u2 d_v0 − d_u0 d_v2,  d_u0 d_v1 − d_u1 d_v0) where ok,
//   else 0 (0 outside the interior); rounded to float32 when the caller blurs it (box > 1).
//
// Then, on the (blurred, float64) cross product n:
//   norm = sqrt((n0 n0 + n1 n1) + n2 n2),  ok &= norm > 1e-12,  n /= max(norm, 1e-12)
//   n = −n where (n0 p0 + n1 p1) + p2 n2 > 0 (facing the camera),  n = 0 where not ok.
//
// Every operation is rounded on its own, in numpy's order (the file is compiled with
// -ffp-contract=off: no fused multiply-add).
#ifndef BIMCAP_RASTER_DEPTH_NORMALS_H_
#define BIMCAP_RASTER_DEPTH_NORMALS_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/image.h"
#include "bimcap/raster/surface_area.h"

namespace bimcap::raster {

// The per-pixel outputs of DepthCross, each a row-major (rows, cols) image (points and cross
// products with 3 interleaved components a pixel, as numpy's (h, w, 3)).
template <typename Cross>
struct DepthCrossOut {
  double* points = nullptr;  // (rows, cols, 3)
  bool* valid = nullptr;     // (rows, cols)
  bool* ok = nullptr;        // (rows, cols) pixels with a normal (interior only)
  Cross* cross = nullptr;    // (rows, cols, 3), float or double
};

// Points, masks and the un-normalised cross products of `depth` (rows, cols). Throws
// RasterError ("step") for step < 1.
template <typename Cross>
void DepthCross(const ImageRef<const float>& depth, const Pinhole& camera, int64_t step,
                const DepthCrossOut<Cross>& out, double jump_offset_m = 0.05);

// Normalises and orients the (rows, cols, 3) cross products `normals` in place against the
// points `points` (rows, cols, 3), and clears `ok` (rows, cols) where the norm is <= 1e-12.
void OrientNormals(int64_t pixels, const double* points, double* normals, bool* ok);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_DEPTH_NORMALS_H_
