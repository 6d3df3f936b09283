// The LiDAR projection's parallax occlusion test (bimcap.fusion.projection._drop_occluded): the
// nearest return in a square window around each return, read at the returns only:
//
//   zmin(p) = min { depth(q) : depth(q) > 0, |row(q) − row(p)| <= r, |col(q) − col(p)| <= r }
//
// (FLT_MAX where the window holds no positive depth): what cv2.erode(np.where(depth > 0, depth,
// FLT_MAX), ones((2 r + 1, 2 r + 1))) gives there, pixels outside the image ignored. A minimum
// of float32 values: nothing is rounded.
#ifndef BIMCAP_RASTER_WINDOW_MIN_H_
#define BIMCAP_RASTER_WINDOW_MIN_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/image.h"

namespace bimcap::raster {

// Writes zmin (count,) for the pixels `at` (count,) (raveled indices of `depth`). Throws
// RasterError ("radius") for radius < 0, ("at") for an index outside the image (nothing is
// written then).
void WindowMinAt(const ImageRef<const float>& depth, const int64_t* at, int64_t count, int radius,
                 float* zmin);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_WINDOW_MIN_H_
