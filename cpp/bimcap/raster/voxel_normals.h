// A LiDAR scan's voxel means and their PCA normals (bimcap.fusion.scan.scan_surface_points).
//
// VoxelMeans, numpy's arithmetic bit for bit:
//   r = sqrt((x x + y y) + z z);  keep r >= min_range and r <= max_range (and finite x, y, z
//   when max_range is infinite)
//   key = floor(p / voxel) per axis, minus its least value over the kept points;
//   flat = (key0 span1 + key1) span2 + key2   (span: the largest key + 1, per axis)
//   one mean per distinct flat key, in ascending key order: the kept points' coordinates summed
//   in input order (np.bincount's order), divided by their count.
//
// PcaNormals, numpy's algorithm (np.mean, np.einsum, np.linalg.eigh), not its rounding:
//   of each query's k neighbours q_i (given), q̄ = Σ q_i / k, C = Σ (q_i − q̄)(q_i − q̄)ᵀ / k,
//   its eigenvalues λ0 <= λ1 <= λ2 and the unit eigenvector of λ0 (the normal; its sign is
//   arbitrary); planar = λ0 <= max_flatness λ1 and λ1 >= min_spread λ2.
// Normals agree with LAPACK's to rounding (tests: 1e-12 after a sign), so a planar test
// decides differently only for a neighbourhood exactly at a threshold.
#ifndef BIMCAP_RASTER_VOXEL_NORMALS_H_
#define BIMCAP_RASTER_VOXEL_NORMALS_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

struct ScanVoxels {
  std::vector<double> means;  // (n, 3) row-major, m, ascending flat key
  int64_t num_kept = 0;       // returns that passed the range test
};

// `points` (count, 3) row-major float64 in the sensor frame (m). Throws RasterError ("voxel")
// for voxel <= 0 or not finite, ("points") for a kept return more than 2^40 voxels away or
// kept returns spread over too many voxels to index.
ScanVoxels VoxelMeans(const double* points, int64_t count, double min_range, double max_range,
                      double voxel);

// `cloud` (cloud_size, 3) row-major; `neighbours` (num_queries, k) row-major indices into it;
// writes `normals` (num_queries, 3) and `planar` (num_queries,). Throws RasterError
// ("neighbours") for k < 1 or an index outside [0, cloud_size) (nothing is written then).
void PcaNormals(const double* cloud, int64_t cloud_size, const int64_t* neighbours,
                int64_t num_queries, int64_t k, double max_flatness, double min_spread,
                double* normals, bool* planar);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_VOXEL_NORMALS_H_
