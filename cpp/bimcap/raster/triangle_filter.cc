#include "bimcap/raster/triangle_filter.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace bimcap::raster {
namespace {

// np.linalg.norm of (dx, dy): the square root of the sum of the squares, left to right.
inline double Length(double dx, double dy) { return std::sqrt(dx * dx + dy * dy); }

}  // namespace

TriangleFilter FilterTriangles(const double* uv, const double* z, int64_t n,
                               const int32_t* triangles, int64_t count, double max_edge,
                               double max_ratio) {
  for (int64_t i = 0; i < 3 * count; ++i) {
    if (triangles[i] < 0 || triangles[i] >= n) {
      throw RasterError("triangles", "vertex " + std::to_string(triangles[i]) + " outside [0, " +
                                         std::to_string(n) + ")");
    }
  }
  TriangleFilter out;
  out.edge.resize(static_cast<size_t>(count));
  out.det.resize(static_cast<size_t>(count));
  for (int64_t t = 0; t < count; ++t) {
    const int32_t* v = triangles + 3 * t;
    const double* a = uv + 2 * v[0];
    const double* b = uv + 2 * v[1];
    const double* c = uv + 2 * v[2];
    // np.maximum.reduce of the three lengths: a NaN anywhere gives NaN (then not good)
    const double ab = Length(a[0] - b[0], a[1] - b[1]);
    const double bc = Length(b[0] - c[0], b[1] - c[1]);
    const double ca = Length(c[0] - a[0], c[1] - a[1]);
    double edge = ab;
    for (const double e : {bc, ca}) edge = (edge >= e || std::isnan(edge)) ? edge : e;
    const double za = z[v[0]], zb = z[v[1]], zc = z[v[2]];
    // np.max / np.min: a NaN depth gives NaN (then not good)
    const double ratio = std::isnan(za) || std::isnan(zb) || std::isnan(zc)
                             ? NAN
                             : std::max({za, zb, zc}) / std::min({za, zb, zc});
    const double e1x = b[0] - a[0], e1y = b[1] - a[1], e2x = c[0] - a[0], e2y = c[1] - a[1];
    const double det = e1x * e2y - e1y * e2x;
    out.edge[t] = edge;
    out.det[t] = det;
    if (edge <= max_edge && ratio <= max_ratio && std::fabs(det) > 2.0) out.good.push_back(t);
  }
  return out;
}

void TriangleCorners(const double* uv, const int32_t* triangles, const std::vector<int64_t>& good,
                     int32_t* corners) {
  for (size_t g = 0; g < good.size(); ++g) {
    const int32_t* v = triangles + 3 * good[g];
    for (int k = 0; k < 3; ++k) {
      for (int d = 0; d < 2; ++d) {
        corners[6 * g + 2 * k + d] = static_cast<int32_t>(std::nearbyint(uv[2 * v[k] + d] * 16));
      }
    }
  }
}

}  // namespace bimcap::raster
