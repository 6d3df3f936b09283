// The k nearest of a set of distinct pixels to each query point (bimcap.features.tracks.
// unsupported_depths: the LiDAR returns nearest each keypoint), as scipy's cKDTree gives them:
//
//   d² = (x − u)² + (y − v)²      (each square rounded, then the sum: cKDTree's p = 2 distance)
//
// in ascending d², ties in ascending index (cKDTree breaks ties in the order its tree visits
// them, so two points at exactly the same distance may come in the other order there).
//
// The pixels are given row by row, as np.nonzero lists them: `row_start` (rows + 1,) offsets,
// `cols` (n,) ascending within each row; pixel i is (cols[i], v) for row_start[v] <= i <
// row_start[v + 1]. Each query walks the rows outward from its own, and each row outward from
// its column, and stops where the squared row (column) offset alone exceeds the k-th distance
// found: exact, not approximate.
#ifndef BIMCAP_RASTER_PIXEL_NEIGHBOURS_H_
#define BIMCAP_RASTER_PIXEL_NEIGHBOURS_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// Writes `nearest` (num_queries, k) row-major: indices into the pixels, nearest first.
// `queries` (num_queries, 2) row-major (x, y) in pixels. Throws RasterError ("k") for k outside
// [1, n]; ("row_start") for offsets that do not rise from 0 to n; ("cols") for columns that are
// not ascending within a row; ("queries") for a non-finite query (nothing is written then).
void NearestPixels(const int64_t* row_start, int64_t rows, const int64_t* cols, int64_t n,
                   const double* queries, int64_t num_queries, int k, int64_t* nearest);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PIXEL_NEIGHBOURS_H_
