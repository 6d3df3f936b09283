// Depth moved onto fitted planes along the pixel rays: the per-pixel half of the planar
// smoothing (bimcap.fusion.completion._smooth_region), in numpy's arithmetic bit for bit.
//
// For pixel i of a region (ray (x_i, y_i, 1), current depth z_i, index flat_i into the image)
// and its K planes n_k · p + d_k = 0 (unit n_k):
//
//   K = 1:  k = 0, every pixel near
//   K > 1:  dist_ik = |t_ik + d_k| with t_ik = p_i · n_k, given (numpy's product) or formed
//           here from p_i = (x_i z_i, y_i z_i, z_i) as OpenBLAS's matrix-matrix product forms
//           it on CPUs with fused multiply-add, fma(p2, n2, fma(p1, n1, p0 n0)) (numpy's
//           `p @ n.T` of two rows or more, bit for bit), k = the first arg-min of dist_i
//           (np.argmin: the first NaN if any), near = min_k dist_ik <= assign_threshold (np.minimum
//           column by column: a NaN makes it false)
//   denom = (x_i n_k0 + y_i n_k1) + n_k2,   z = (−d_k) / denom
//   out[flat_i] = float32(z)  where z is finite, z > 0, |z − z_i| <= max_change_rel · z_i and near
//
// Every other operation is rounded on its own, in numpy's order (the file is compiled with
// -ffp-contract=off: no contraction into fused multiply-adds); other pixels of `out` are left as
// they are.
#ifndef BIMCAP_RASTER_PLANE_DEPTH_H_
#define BIMCAP_RASTER_PLANE_DEPTH_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// One region's pixels: `count` rays (x, y, 1), their current depths (metres) and their indices
// into the raveled image.
struct RegionPixels {
  const double* ray_x = nullptr;
  const double* ray_y = nullptr;
  const double* depth = nullptr;
  const int64_t* flat = nullptr;
  int64_t count = 0;
};

// The thresholds of the move (bimcap.fusion.completion.PlanarSmoothingOptions).
struct PlaneMove {
  double assign_threshold_m = 0.0;  // K > 1: the nearest plane must be this close (metres)
  double max_change_rel = 0.0;      // no pixel moves by more than this fraction of its depth
};

// Moves the region's pixels of `out` (raveled image of `out_size` floats) onto `planes`, a
// row-major (plane_count, 4) table of n0 n1 n2 d. `products`: the row-major (count, plane_count)
// table p_i · n_k, or null to form it here (ignored with one plane). Returns the number of pixels
// moved. Throws RasterError ("flat") for an index outside [0, out_size) and ("planes") for
// plane_count < 1, before anything is written.
int64_t MoveOntoPlanes(const RegionPixels& region, const double* planes, int64_t plane_count,
                       const double* products, const PlaneMove& move, float* out, int64_t out_size);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PLANE_DEPTH_H_
