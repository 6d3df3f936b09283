// The surface area each pixel of an undistorted z-depth map covers (semantic sampling's density,
// bimcap.frontend.semantic_map.pixel_surface_area), in numpy's arithmetic bit for bit.
//
//   p(u, v) = z · (x_u, y_v, 1),   x_u = (u − cx) / fx,  y_v = (v − cy) / fy
//   p_u, p_v: np.gradient of each component along u / v (central (a[i+1] − a[i−1]) / 2,
//             one-sided a[1] − a[0] and a[n−1] − a[n−2] at the ends)
//   n = p_u × p_v,   cos θ = clip(|n·p| / (|n| |p|), min_cos, 1)   (1 where not finite)
//   cos α = z / |p| (1 where |p| = 0)
//   area = z² cos α / (fx fy) / cos θ  where z > 0, else 0                         (m²)
//
// Every product, sum (left to right: n0² + n1² + n2², x² + y² + z², n0 x + n1 y + n2 z),
// square root and quotient is rounded on its own, in the order numpy evaluates the Python
// expression; the file is compiled with -ffp-contract=off (no fused multiply-add).
#ifndef BIMCAP_RASTER_SURFACE_AREA_H_
#define BIMCAP_RASTER_SURFACE_AREA_H_

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/image.h"

namespace bimcap::raster {

// The pinhole intrinsics of the depth map (px).
struct Pinhole {
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
};

// area (rows, cols) from depth (rows, cols), both at least 2 × 2. Throws RasterError ("depth")
// for a smaller or mismatched image.
void PixelSurfaceArea(const ImageRef<const double>& depth, const Pinhole& camera, double min_cos,
                      const ImageRef<double>& area);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_SURFACE_AREA_H_
