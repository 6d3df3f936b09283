// The Delaunay triangulation of the linear depth completion's sparse returns, by a sweep of the
// convex hull (Sinclair's "S-hull": the points taken in order of their distance from a seed
// triangle's circumcentre, each joined to the hull edges it sees, then Lawson's edge flips):
//
//   1. seed: the point nearest the bounding box's centre, the point nearest it, and the point
//      that makes the smallest circumcircle with both, turned counter-clockwise;
//   2. every other point, by increasing squared distance to the seed's circumcentre (ties by x,
//      then y; a point equal to the previous one is skipped), lies outside the hull of those
//      before it: it is joined to each hull edge it sees strictly from outside (orientation < 0
//      for the counter-clockwise hull), found from a hash of the hull's vertices by their
//      pseudo-angle around the circumcentre;
//   3. every new triangle's edges are flipped while the opposite vertex lies strictly inside the
//      circumcircle (in-circle determinant > 0), an explicit stack instead of recursion.
//
// Orientation and in-circle tests are evaluated in double with the error bounds of Shewchuk's
// adaptive predicates, and again in long double when the double result is within the bound.
// bimcap.fusion.completion.complete_linear used scipy.spatial.Delaunay (Qhull, "Qbb Qc Qz Q12"):
// the same triangles wherever the points are in general position (no four on a circle, the
// hull without three collinear corners), in another order; for the ~3,600 returns of a 516 × 386
// frame Qhull took 11-18 ms, this 1.3-1.8 ms (load 15-16; docs/speed.md, "LiDAR stages, the
// triangulation and the cache writes").
#ifndef BIMCAP_RASTER_DELAUNAY_H_
#define BIMCAP_RASTER_DELAUNAY_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// The Delaunay triangles of n points xy = x0, y0, x1, y1, … (finite): 3 vertex indices a
// triangle, each counter-clockwise (in x right, y up; clockwise on an image's rows), in the order
// the sweep made them. Throws RasterError("points") for fewer than 3 distinct points, points all
// on one line, or a non-finite coordinate.
std::vector<int32_t> DelaunayTriangles(const double* xy, int64_t n);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_DELAUNAY_H_
