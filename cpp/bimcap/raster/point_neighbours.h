// The k nearest of a 3-D point set to each query point (bimcap.fusion.scan.scan_surface_points:
// the voxel means nearest each candidate), as scipy's cKDTree gives them:
//
//   d² = ((x − x')² + (y − y')²) + (z − z')²   (each square rounded, summed in that order)
//
// in ascending d², ties in ascending index (cKDTree takes them in the order its tree visits
// them). The points are bucketed in a grid of cubes of side `cell` (a hash of the occupied
// cubes); each query visits the shells of cubes around its own, nearest first, skips a cube
// whose box is further than the k-th distance found, and stops once every cube not visited is:
// exact, not approximate, for any cell size (the cell size only sets the cost; about the
// points' spacing is best).
#ifndef BIMCAP_RASTER_POINT_NEIGHBOURS_H_
#define BIMCAP_RASTER_POINT_NEIGHBOURS_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// Writes `nearest` (num_queries, k) row-major: indices into `points` (n, 3) row-major, nearest
// first. `queries` (num_queries, 3) row-major. Throws RasterError ("k") for k outside [1, n];
// ("cell") for a cell that is not finite and > 0; ("points") / ("queries") for a coordinate
// that is not finite or more than 2^40 cells from the origin (nothing is written then).
void NearestPoints(const double* points, int64_t n, const double* queries, int64_t num_queries,
                   int k, double cell, int64_t* nearest);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_POINT_NEIGHBOURS_H_
