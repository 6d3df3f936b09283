#include "bimcap/raster/window_min.h"

#include <algorithm>
#include <cfloat>
#include <string>

namespace bimcap::raster {

void WindowMinAt(const ImageRef<const float>& depth, const int64_t* at, int64_t count, int radius,
                 float* zmin) {
  if (radius < 0) throw RasterError("radius", "must be >= 0, got " + std::to_string(radius));
  const int64_t h = depth.rows, w = depth.cols;
  CheckPixelIndices(at, 0, count, h * w, "at");
  for (int64_t i = 0; i < count; ++i) {
    const int64_t v = at[i] / w, u = at[i] % w;
    const int64_t v0 = std::max<int64_t>(v - radius, 0), v1 = std::min<int64_t>(v + radius, h - 1);
    const int64_t u0 = std::max<int64_t>(u - radius, 0), u1 = std::min<int64_t>(u + radius, w - 1);
    float best = FLT_MAX;
    for (int64_t y = v0; y <= v1; ++y) {
      const float* row = depth.data + y * w;
      for (int64_t x = u0; x <= u1; ++x) {
        const float z = row[x];
        if (z > 0.0f && z < best) best = z;
      }
    }
    zmin[i] = best;
  }
}

}  // namespace bimcap::raster
