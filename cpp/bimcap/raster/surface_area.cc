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

// One pixel's area from its point (x, y, z) and gradients (the header's formula).
inline __attribute__((always_inline)) double Area(double x, double y, double z, double xu,
                                                  double yu, double zu, double xv, double yv,
                                                  double zv, double min_cos, double fxfy) {
  const double n0 = yu * zv - zu * yv;
  const double n1 = zu * xv - xu * zv;
  const double n2 = xu * yv - yu * xv;
  const double nn = std::sqrt(n0 * n0 + n1 * n1 + n2 * n2);
  const double pn = std::sqrt(x * x + y * y + z * z);
  // Every quotient is formed whatever the branch taken (selects, not jumps: the loop
  // vectorises); the values are those of the branches.
  const double c = std::fabs(n0 * x + n1 * y + n2 * z) / (nn * pn);
  // not finite → 1 (c − c is 0 exactly for a finite c, NaN for ±inf and NaN)
  double cos_theta = c - c == 0.0 ? c : 1.0;
  // np.clip(c, min_cos, 1.0) = min(max(c, min_cos), 1.0)
  cos_theta = cos_theta < min_cos ? min_cos : cos_theta;
  cos_theta = cos_theta > 1.0 ? 1.0 : cos_theta;
  const double z_over_pn = z / pn;
  const double cos_alpha = pn > 0 ? z_over_pn : 1.0;
  const double area = z * z * cos_alpha / fxfy / cos_theta;
  return z > 0 ? area : 0.0;  // also NaN: np.where(z > 0, …, 0)
}

// The columns 1 … w − 2 of one row: central differences along u; along v the rows `below` and
// `above` (v + 1 and v − 1, or v + 1 and v, or v and v − 1 at the ends), times `v_scale` (1/2 for
// a central difference: x · 0.5 is x / 2 exactly, as x · 1 is x). Straight-line code that
// vectorises; on x86-64 with GCC or Clang an AVX2 clone is picked at load time where the CPU has
// it (no fused multiply-add in either: each operation rounded on its own, the same bits).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("avx2", "default")))
#endif
void InteriorRow(const double* __restrict z_row, const double* __restrict below,
                 const double* __restrict above, const double* __restrict ray_x, double ry,
                 double ry_below, double ry_above, double v_scale, int64_t w, double min_cos,
                 double fxfy, double* __restrict out) {
  for (int64_t u = 1; u < w - 1; ++u) {
    const double z = z_row[u];
    const double xu = (ray_x[u + 1] * z_row[u + 1] - ray_x[u - 1] * z_row[u - 1]) * 0.5;
    const double yu = (ry * z_row[u + 1] - ry * z_row[u - 1]) * 0.5;
    const double zu = (z_row[u + 1] - z_row[u - 1]) * 0.5;
    const double xv = (ray_x[u] * below[u] - ray_x[u] * above[u]) * v_scale;
    const double yv = (ry_below * below[u] - ry_above * above[u]) * v_scale;
    const double zv = (below[u] - above[u]) * v_scale;
    out[u] = Area(ray_x[u] * z, ry * z, z, xu, yu, zu, xv, yv, zv, min_cos, fxfy);
  }
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
    const int64_t lo = v == 0 ? 0 : v - 1, hi = v == h - 1 ? h - 1 : v + 1;
    InteriorRow(depth.data + v * w, depth.data + hi * w, depth.data + lo * w, ray_x.data(),
                ray_y[v], ray_y[hi], ray_y[lo], v == 0 || v == h - 1 ? 1.0 : 0.5, w, min_cos, fxfy,
                area.data + v * w);
  }
  // the first and last columns (one-sided differences along u)
  for (int64_t v = 0; v < h; ++v) {
    const double* z_row = depth.data + v * w;
    const double ry = ray_y[v];
    for (const int64_t u : {int64_t{0}, w - 1}) {
      const double z = z_row[u];
      // The point's components at a neighbour along u (same row) and along v (same column).
      auto x_u = [&](int64_t k) { return ray_x[k] * z_row[k]; };
      auto y_u = [&](int64_t k) { return ry * z_row[k]; };
      auto z_u = [&](int64_t k) { return z_row[k]; };
      auto x_v = [&](int64_t k) { return ray_x[u] * depth.data[k * w + u]; };
      auto y_v = [&](int64_t k) { return ray_y[k] * depth.data[k * w + u]; };
      auto z_v = [&](int64_t k) { return depth.data[k * w + u]; };
      const double xu = Gradient(x_u, u, w), yu = Gradient(y_u, u, w), zu = Gradient(z_u, u, w);
      const double xv = Gradient(x_v, v, h), yv = Gradient(y_v, v, h), zv = Gradient(z_v, v, h);
      area.data[v * w + u] = Area(ray_x[u] * z, ry * z, z, xu, yu, zu, xv, yv, zv, min_cos, fxfy);
    }
  }
}

}  // namespace bimcap::raster
