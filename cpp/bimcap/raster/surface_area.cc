#include "bimcap/raster/surface_area.h"

#include <cmath>
#include <string>
#include <vector>

namespace bimcap::raster {
namespace {

// np.gradient's entry i of a[0 … n − 1] (a[k] = at(k)), unit spacing, first-order ends.
template <typename At>
inline double Gradient(const At& at, int64_t i, int64_t n) {
  if (i == 0) return at(1) - at(0);
  if (i == n - 1) return at(n - 1) - at(n - 2);
  return (at(i + 1) - at(i - 1)) / 2.0;
}

}  // namespace

void PixelSurfaceArea(const ImageRef<const double>& depth, const Pinhole& camera, double min_cos,
                      const ImageRef<double>& area) {
  const int64_t h = depth.rows, w = depth.cols;
  if (h < 2 || w < 2) {
    throw RasterError("depth", "must be (H, W) with H, W >= 2, got (" + std::to_string(h) + ", " +
                                   std::to_string(w) + ")");
  }
  if (area.rows != h || area.cols != w) throw RasterError("area", "shape differs from depth's");
  std::vector<double> ray_x(w), ray_y(h);
  for (int64_t u = 0; u < w; ++u) ray_x[u] = (static_cast<double>(u) - camera.cx) / camera.fx;
  for (int64_t v = 0; v < h; ++v) ray_y[v] = (static_cast<double>(v) - camera.cy) / camera.fy;
  const double fxfy = camera.fx * camera.fy;
  for (int64_t v = 0; v < h; ++v) {
    const double* z_row = depth.data + v * w;
    double* out = area.data + v * w;
    const double ry = ray_y[v];
    for (int64_t u = 0; u < w; ++u) {
      const double z = z_row[u];
      if (!(z > 0)) {  // also NaN: np.where(z > 0, …, 0)
        out[u] = 0.0;
        continue;
      }
      // The point's components at a neighbour along u (same row) and along v (same column).
      auto x_u = [&](int64_t k) { return ray_x[k] * z_row[k]; };
      auto y_u = [&](int64_t k) { return ry * z_row[k]; };
      auto z_u = [&](int64_t k) { return z_row[k]; };
      auto x_v = [&](int64_t k) { return ray_x[u] * depth.data[k * w + u]; };
      auto y_v = [&](int64_t k) { return ray_y[k] * depth.data[k * w + u]; };
      auto z_v = [&](int64_t k) { return depth.data[k * w + u]; };
      const double xu = Gradient(x_u, u, w), yu = Gradient(y_u, u, w), zu = Gradient(z_u, u, w);
      const double xv = Gradient(x_v, v, h), yv = Gradient(y_v, v, h), zv = Gradient(z_v, v, h);
      const double x = ray_x[u] * z, y = ry * z;
      const double n0 = yu * zv - zu * yv;
      const double n1 = zu * xv - xu * zv;
      const double n2 = xu * yv - yu * xv;
      const double nn = std::sqrt(n0 * n0 + n1 * n1 + n2 * n2);
      const double pn = std::sqrt(x * x + y * y + z * z);
      double cos_theta = std::fabs(n0 * x + n1 * y + n2 * z) / (nn * pn);
      if (!std::isfinite(cos_theta)) cos_theta = 1.0;
      // np.clip(c, min_cos, 1.0) = min(max(c, min_cos), 1.0)
      cos_theta = cos_theta < min_cos ? min_cos : cos_theta;
      cos_theta = cos_theta > 1.0 ? 1.0 : cos_theta;
      const double cos_alpha = pn > 0 ? z / pn : 1.0;
      out[u] = z * z * cos_alpha / fxfy / cos_theta;
    }
  }
}

}  // namespace bimcap::raster
