#include "bimcap/raster/region_rays.h"

namespace bimcap::raster {

RegionRays GatherRegionRays(const int64_t* flat, int64_t count, int64_t width, int64_t size,
                            const PinholeRays& camera, const float* depth, const float* measured) {
  CheckPixelIndices(flat, 0, count, size, "flat");
  RegionRays out;
  out.x.resize(static_cast<size_t>(count));
  out.y.resize(static_cast<size_t>(count));
  out.cur.resize(static_cast<size_t>(count));
  for (int64_t i = 0; i < count; ++i) {
    const int64_t v = flat[i] / width, u = flat[i] % width;
    const double x = (static_cast<double>(u) - camera.cx) / camera.fx;
    const double y = (static_cast<double>(v) - camera.cy) / camera.fy;
    out.x[i] = x;
    out.y[i] = y;
    out.cur[i] = static_cast<double>(depth[flat[i]]);
    if (measured != nullptr) {
      const double z = static_cast<double>(measured[flat[i]]);
      if (z > 0.0) out.returns.insert(out.returns.end(), {x * z, y * z, z});
    }
  }
  return out;
}

}  // namespace bimcap::raster
