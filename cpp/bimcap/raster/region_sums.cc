#include "bimcap/raster/region_sums.h"

#include <algorithm>
#include <string>
#include <vector>

namespace bimcap::raster {

void RegionPlaneSums(const ImageRef<const int32_t>& comp, const ImageRef<const bool>& valid,
                     const ImageRef<const float>& depth, const Pinhole& camera, int64_t num_regions,
                     int64_t* count, double* ata, double* atb) {
  const int64_t h = comp.rows, w = comp.cols;
  if (valid.rows != h || valid.cols != w) throw RasterError("valid", "shape differs from comp's");
  if (depth.rows != h || depth.cols != w) throw RasterError("depth", "shape differs from comp's");
  for (int64_t i = 0; i < h * w; ++i) {
    if (valid.data[i] && (comp.data[i] < 0 || comp.data[i] >= num_regions)) {
      throw RasterError("comp", "region " + std::to_string(comp.data[i]) + " outside [0, " +
                                    std::to_string(num_regions) + ")");
    }
  }
  std::fill(count, count + num_regions, int64_t{0});
  std::fill(ata, ata + 9 * num_regions, 0.0);
  std::fill(atb, atb + 3 * num_regions, 0.0);
  std::vector<double> ray_x(static_cast<size_t>(w));
  for (int64_t u = 0; u < w; ++u) ray_x[u] = (static_cast<double>(u) - camera.cx) / camera.fx;
  for (int64_t v = 0; v < h; ++v) {
    const double y = (static_cast<double>(v) - camera.cy) / camera.fy;
    for (int64_t u = 0; u < w; ++u) {
      if (!valid.at(v, u)) continue;
      const int32_t c = comp.at(v, u);
      const double x = ray_x[u];
      const double inv = 1.0 / static_cast<double>(depth.at(v, u));
      double* a = ata + 9 * c;
      double* b = atb + 3 * c;
      ++count[c];
      b[0] += x * inv;
      b[1] += y * inv;
      b[2] += inv;
      a[0] += x * x;
      a[1] += x * y;
      a[2] += x;
      a[4] += y * y;
      a[5] += y;
    }
  }
  for (int64_t c = 0; c < num_regions; ++c) {
    double* a = ata + 9 * c;
    a[3] = a[1];
    a[6] = a[2];
    a[7] = a[5];
    a[8] = static_cast<double>(count[c]);
  }
}

}  // namespace bimcap::raster
