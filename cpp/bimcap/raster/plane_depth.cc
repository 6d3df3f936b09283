#include "bimcap/raster/plane_depth.h"

#include <cmath>
#include <string>
#include <vector>

#include "bimcap/raster/image.h"

namespace bimcap::raster {

// On x86-64 with GCC or Clang an FMA clone (fused multiply-add in hardware, for the products)
// is picked at load time where the CPU has it; both clones form the same numbers.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("fma", "default")))
#endif
int64_t
MoveOntoPlanes(const RegionPixels& region, const double* planes, int64_t plane_count,
               const double* products, const PlaneMove& move, float* out, int64_t out_size) {
  if (plane_count < 1) throw RasterError("planes", "needs at least one plane");
  CheckPixelIndices(region.flat, 0, region.count, out_size, "flat");
  int64_t moved = 0;
  std::vector<double> row(products == nullptr ? static_cast<size_t>(plane_count) : 0);
  for (int64_t i = 0; i < region.count; ++i) {
    int64_t best = 0;
    bool near = true;
    if (plane_count > 1) {
      const double* t = products + i * plane_count;
      if (products == nullptr) {  // p = (x z, y z, z), t_k = p · n_k as a matrix product forms it
        const double z = region.depth[i];
        const double p0 = region.ray_x[i] * z, p1 = region.ray_y[i] * z;
        for (int64_t k = 0; k < plane_count; ++k) {
          const double* n = planes + 4 * k;
          row[k] = std::fma(z, n[2], std::fma(p1, n[1], p0 * n[0]));
        }
        t = row.data();
      }
      // np.argmin (the first minimum; the first NaN if any) and np.minimum taken column by
      // column (NaN-propagating) of |t_k + d_k|
      double least = std::fabs(t[0] + planes[3]);
      double nearest = least;
      for (int64_t k = 1; k < plane_count; ++k) {
        const double dist = std::fabs(t[k] + planes[4 * k + 3]);
        if (!std::isnan(least) && (dist < least || std::isnan(dist))) {
          least = dist;
          best = k;
        }
        nearest = (std::isnan(nearest) || std::isnan(dist)) ? NAN : std::fmin(nearest, dist);
      }
      near = nearest <= move.assign_threshold_m;
    }
    const double* plane = planes + 4 * best;
    const double denom = region.ray_x[i] * plane[0] + region.ray_y[i] * plane[1] + plane[2];
    const double z = -plane[3] / denom;
    const double cur = region.depth[i];
    if (near && std::isfinite(z) && z > 0 && std::fabs(z - cur) <= move.max_change_rel * cur) {
      out[region.flat[i]] = RoundToFloat32(z);
      ++moved;
    }
  }
  return moved;
}

}  // namespace bimcap::raster
