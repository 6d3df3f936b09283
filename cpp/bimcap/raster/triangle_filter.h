// Which Delaunay triangles the linear depth completion interpolates in
// (bimcap.fusion.completion.complete_linear), in numpy's arithmetic bit for bit:
//
//   a, b, c = uv[t0], uv[t1], uv[t2]                       (px)
//   edge = max(|a − b|, |b − c|, |c − a|)                  (|d| = sqrt(dx dx + dy dy))
//   ratio = max(z[t0], z[t1], z[t2]) / min(z[t0], z[t1], z[t2])
//   det = (b − a)x (c − a)y − (b − a)y (c − a)x           (twice the signed area, px²)
//   good = edge <= max_edge and ratio <= max_ratio and |det| > 2
//
// and the corners of the good ones in 1/16 px (rint(16 · uv) as int32, cv2.fillConvexPoly's
// fixed point). Each operation is rounded on its own (-ffp-contract=off).
#ifndef BIMCAP_RASTER_TRIANGLE_FILTER_H_
#define BIMCAP_RASTER_TRIANGLE_FILTER_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

struct TriangleFilter {
  std::vector<double> edge;   // (T,) the longest edge, px
  std::vector<double> det;    // (T,) twice the signed area, px²
  std::vector<int64_t> good;  // ascending indices of the good triangles
};

// `uv` (n, 2) and `z` (n,) row-major; `triangles` (count, 3) vertex indices. Throws RasterError
// ("triangles") for an index outside [0, n).
TriangleFilter FilterTriangles(const double* uv, const double* z, int64_t n,
                               const int32_t* triangles, int64_t count, double max_edge,
                               double max_ratio);

// (good.size(), 3, 2) corners rint(16 · uv) of the triangles `good`, as int32.
void TriangleCorners(const double* uv, const int32_t* triangles, const std::vector<int64_t>& good,
                     int32_t* corners);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_TRIANGLE_FILTER_H_
