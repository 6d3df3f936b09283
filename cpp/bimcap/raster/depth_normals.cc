#include "bimcap/raster/depth_normals.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

namespace bimcap::raster {
namespace {

template <typename Cross>
Cross AsCross(double x) {
  if constexpr (std::is_same_v<Cross, float>) {
    return RoundToFloat32(x);
  } else {
    return x;
  }
}

}  // namespace

template <typename Cross>
void DepthCross(const ImageRef<const float>& depth, const Pinhole& camera, int64_t step,
                const DepthCrossOut<Cross>& out, double jump_offset_m) {
  if (step < 1) throw RasterError("step", "must be >= 1 px, got " + std::to_string(step));
  const int64_t h = depth.rows, w = depth.cols, s = step;
  std::vector<double> ray_x(w), ray_y(h);
  for (int64_t u = 0; u < w; ++u) ray_x[u] = (static_cast<double>(u) - camera.cx) / camera.fx;
  for (int64_t v = 0; v < h; ++v) ray_y[v] = (static_cast<double>(v) - camera.cy) / camera.fy;
  for (int64_t v = 0; v < h; ++v) {
    for (int64_t u = 0; u < w; ++u) {
      const int64_t i = v * w + u;
      const double z = depth.data[i];
      out.points[3 * i] = ray_x[u] * z;
      out.points[3 * i + 1] = ray_y[v] * z;
      out.points[3 * i + 2] = z;
      out.valid[i] = z > 0;
      out.ok[i] = false;
      out.cross[3 * i] = out.cross[3 * i + 1] = out.cross[3 * i + 2] = Cross{0};
    }
  }
  for (int64_t v = s; v < h - s; ++v) {
    for (int64_t u = s; u < w - s; ++u) {
      const int64_t i = v * w + u;
      const int64_t left = i - s, right = i + s, up = i - s * w, down = i + s * w;
      const double z = out.points[3 * i + 2];
      const double zl = out.points[3 * left + 2], zr = out.points[3 * right + 2];
      const double zu = out.points[3 * up + 2], zd = out.points[3 * down + 2];
      // metres: farther apart in depth is across an edge
      const double jump = 0.05 * z + jump_offset_m;
      const bool ok = z > 0 && zr > 0 && zl > 0 && zd > 0 && zu > 0 &&
                      std::fabs(zr - zl) < 2 * jump && std::fabs(zd - zu) < 2 * jump;
      out.ok[i] = ok;
      if (!ok) continue;
      const double* pr = out.points + 3 * right;
      const double* pl = out.points + 3 * left;
      const double* pd = out.points + 3 * down;
      const double* pu = out.points + 3 * up;
      const double du0 = pr[0] - pl[0], du1 = pr[1] - pl[1], du2 = pr[2] - pl[2];
      const double dv0 = pd[0] - pu[0], dv1 = pd[1] - pu[1], dv2 = pd[2] - pu[2];
      out.cross[3 * i] = AsCross<Cross>(du1 * dv2 - du2 * dv1);
      out.cross[3 * i + 1] = AsCross<Cross>(du2 * dv0 - du0 * dv2);
      out.cross[3 * i + 2] = AsCross<Cross>(du0 * dv1 - du1 * dv0);
    }
  }
}

template void DepthCross<float>(const ImageRef<const float>&, const Pinhole&, int64_t,
                                const DepthCrossOut<float>&, double);
template void DepthCross<double>(const ImageRef<const float>&, const Pinhole&, int64_t,
                                 const DepthCrossOut<double>&, double);

void OrientNormals(int64_t pixels, const double* points, double* normals, bool* ok) {
  for (int64_t i = 0; i < pixels; ++i) {
    double* n = normals + 3 * i;
    const double* p = points + 3 * i;
    const double norm = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    ok[i] = ok[i] && norm > 1e-12;
    if (!ok[i]) {
      n[0] = n[1] = n[2] = 0.0;
      continue;
    }
    const double scale = std::max(norm, 1e-12);
    n[0] /= scale;
    n[1] /= scale;
    n[2] /= scale;
    if (n[0] * p[0] + n[1] * p[1] + n[2] * p[2] > 0) {  // face the camera
      n[0] = -n[0];
      n[1] = -n[1];
      n[2] = -n[2];
    }
  }
}

}  // namespace bimcap::raster
