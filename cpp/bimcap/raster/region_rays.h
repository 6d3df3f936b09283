// The planar smoothing's per-region inputs (bimcap.fusion.completion._smooth_region), gathered
// in one pass, in numpy's float64 arithmetic bit for bit:
//
//   x = (u − cx) / fx,  y = (v − cy) / fy        (the pinhole ray (x, y, 1) of pixel (u, v))
//   cur = depth(u, v)                            (float32 widened)
//   returns: (x z, y z, z) for the pixels whose measured depth z > 0, in the region's order
#ifndef BIMCAP_RASTER_REGION_RAYS_H_
#define BIMCAP_RASTER_REGION_RAYS_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

struct PinholeRays {
  double fx, fy, cx, cy;
};

struct RegionRays {
  std::vector<double> x, y, cur;
  std::vector<double> returns;  // (R, 3) row-major
};

// `flat` (count,) raveled pixels of an image `width` wide holding `size` pixels; `depth` and
// `measured` (size,) (measured null: no returns). Throws RasterError ("flat") for a pixel
// outside the image (nothing returned then).
RegionRays GatherRegionRays(const int64_t* flat, int64_t count, int64_t width, int64_t size,
                            const PinholeRays& camera, const float* depth, const float* measured);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_REGION_RAYS_H_
