// The normal equations of each labelled region's inverse-depth plane fit (the label orientation
// check, bimcap.frontend.semantic_map._region_plane_normals), in numpy's arithmetic bit for bit:
//
//   for every pixel (v, u) of `valid`, in row-major order, of region c = comp[v, u]:
//     x = (u − cx) / fx,  y = (v − cy) / fy,  w = 1 / z   (z: float32 depth, as float64)
//     count[c] += 1
//     atb[c] += (x w, y w, w)
//     ata[c] += [[x x, x y, x], [x y, y y, y], [x, y, count]]   (symmetric; the last entry is
//                                                              the count)
//
// Each sum adds the pixels in row-major order, as np.bincount adds its weights; each product is
// rounded once (the file is compiled with -ffp-contract=off).
#ifndef BIMCAP_RASTER_REGION_SUMS_H_
#define BIMCAP_RASTER_REGION_SUMS_H_

#include <cstdint>

#include "bimcap/raster/image.h"
#include "bimcap/raster/surface_area.h"

namespace bimcap::raster {

// `count` (num_regions,), `ata` (num_regions, 3, 3) and `atb` (num_regions, 3), row-major,
// filled (zeros where a region has no valid pixel). Throws RasterError ("comp") for a valid
// pixel's region outside [0, num_regions) (nothing is written then), ("valid"/"depth") for a
// shape unlike comp's.
void RegionPlaneSums(const ImageRef<const int32_t>& comp, const ImageRef<const bool>& valid,
                     const ImageRef<const float>& depth, const Pinhole& camera, int64_t num_regions,
                     int64_t* count, double* ata, double* atb);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_REGION_SUMS_H_
