#include "bimcap/raster/voxel_normals.h"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

namespace bimcap::raster {
namespace {

constexpr double kMaxKey = 0x1p40;

// The bits an index below n needs (at least 1).
int IndexBits(int64_t n) {
  int bits = 1;
  while (bits < 62 && (int64_t{1} << bits) < n) ++bits;
  return bits;
}

}  // namespace

ScanVoxels VoxelMeans(const double* points, int64_t count, double min_range, double max_range,
                      double voxel) {
  if (!(voxel > 0.0) || !std::isfinite(voxel)) {
    throw RasterError("voxel", "must be > 0 and finite, got " + std::to_string(voxel));
  }
  ScanVoxels out;
  const bool check_finite = !std::isfinite(max_range);
  std::vector<int64_t> kept;
  kept.reserve(static_cast<size_t>(count));
  for (int64_t i = 0; i < count; ++i) {
    const double x = points[3 * i], y = points[3 * i + 1], z = points[3 * i + 2];
    const double r = std::sqrt(x * x + y * y + z * z);
    if (!(r >= min_range && r <= max_range)) continue;
    if (check_finite && !(std::isfinite(x) && std::isfinite(y) && std::isfinite(z))) continue;
    kept.push_back(i);
  }
  const auto n = static_cast<int64_t>(kept.size());
  out.num_kept = n;
  if (n == 0) return out;
  // keys per axis, shifted to start at 0
  std::vector<int64_t> key(static_cast<size_t>(3 * n));
  int64_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::numeric_limits<int64_t>::max();
    hi[a] = std::numeric_limits<int64_t>::min();
  }
  for (int64_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor(points[3 * kept[i] + a] / voxel);
      if (!(std::fabs(f) < kMaxKey)) {
        throw RasterError("points", "return " + std::to_string(kept[i]) +
                                        " lies more than 2^40 voxels from the sensor");
      }
      const auto k = static_cast<int64_t>(f);
      key[3 * i + a] = k;
      lo[a] = std::min(lo[a], k);
      hi[a] = std::max(hi[a], k);
    }
  }
  int64_t span[3];
  for (int a = 0; a < 3; ++a) span[a] = hi[a] - lo[a] + 1;
  // the flat keys sorted, and inside a key the points in input order (the order np.bincount
  // sums them in): one sort of the keys with the positions packed into their low bits where
  // both fit in 63 bits, else of (key, position) pairs
  const double flat_max =
      static_cast<double>(span[0]) * static_cast<double>(span[1]) * static_cast<double>(span[2]);
  if (!(flat_max < 0x1p62)) {
    throw RasterError(
        "points", "the kept returns span " + std::to_string(flat_max) + " voxels, more than 2^62");
  }
  std::vector<std::pair<int64_t, int64_t>> order(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    const int64_t* k = &key[3 * i];
    order[i] = {((k[0] - lo[0]) * span[1] + (k[1] - lo[1])) * span[2] + (k[2] - lo[2]), i};
  }
  const int bits = IndexBits(n);
  if (flat_max < std::ldexp(1.0, 62 - bits)) {
    std::vector<int64_t> packed(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) packed[i] = (order[i].first << bits) | i;
    std::sort(packed.begin(), packed.end());
    for (int64_t i = 0; i < n; ++i) {
      order[i] = {packed[i] >> bits, packed[i] & ((int64_t{1} << bits) - 1)};
    }
  } else {
    std::sort(order.begin(), order.end());
  }
  std::vector<int64_t> keys;
  std::vector<int64_t> counts;
  std::vector<int64_t> slot(static_cast<size_t>(n));  // each point's voxel
  for (const auto& [flat, i] : order) {
    if (keys.empty() || keys.back() != flat) {
      keys.push_back(flat);
      counts.push_back(0);
    }
    slot[i] = static_cast<int64_t>(keys.size()) - 1;
    ++counts.back();
  }
  std::vector<double>& sums = out.means;
  sums.assign(3 * keys.size(), 0.0);
  for (int64_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) sums[3 * slot[i] + a] += points[3 * kept[i] + a];
  }
  for (size_t j = 0; j < keys.size(); ++j) {
    for (size_t a = 0; a < 3; ++a) sums[3 * j + a] /= static_cast<double>(counts[j]);
  }
  return out;
}

void PcaNormals(const double* cloud, int64_t cloud_size, const int64_t* neighbours,
                int64_t num_queries, int64_t k, double max_flatness, double min_spread,
                double* normals, bool* planar) {
  if (k < 1) throw RasterError("neighbours", "needs at least one column");
  for (int64_t m = 0; m < num_queries * k; ++m) {
    if (neighbours[m] < 0 || neighbours[m] >= cloud_size) {
      throw RasterError("neighbours", "index " + std::to_string(neighbours[m]) + " outside [0, " +
                                          std::to_string(cloud_size) + ")");
    }
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  for (int64_t i = 0; i < num_queries; ++i) {
    const int64_t* nb = &neighbours[i * k];
    double mean[3] = {0.0, 0.0, 0.0};
    for (int64_t m = 0; m < k; ++m) {
      for (int a = 0; a < 3; ++a) mean[a] += cloud[3 * nb[m] + a];
    }
    for (double& v : mean) v /= static_cast<double>(k);
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (int64_t m = 0; m < k; ++m) {
      const double* p = &cloud[3 * nb[m]];
      const Eigen::Vector3d d(p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]);
      cov += d * d.transpose();
    }
    cov /= static_cast<double>(k);
    solver.compute(cov);  // eigenvalues ascending
    const Eigen::Vector3d& ev = solver.eigenvalues();
    const Eigen::Vector3d normal = solver.eigenvectors().col(0);
    for (int a = 0; a < 3; ++a) normals[3 * i + a] = normal[a];
    planar[i] = ev[0] <= max_flatness * ev[1] && ev[1] >= min_spread * ev[2];
  }
}

}  // namespace bimcap::raster
