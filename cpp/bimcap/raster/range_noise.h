// The range noise σ of a spinning LiDAR's scan, from the scan alone
// (bimcap.segmentation.geometric.scan_range_noise), in numpy's arithmetic bit for bit:
//
//   r = sqrt((x x + y y) + z z); keep finite r > 0
//   elevation = degrees(asin(clip(z / r, -1, 1))),  azimuth = degrees(atan2(y, x))
//   ring = rint(elevation / ring_bin_deg)           (degrees(a) = a · (180 / π))
//   the returns sorted by (ring, azimuth, input position)  (np.lexsort, stable)
//   triples k-1, k, k+1 of one ring with azimuth steps a = az[k] − az[k−1], b = az[k+1] − az[k]
//   below max_step_deg and |a − b| < 0.1 max_step_deg qualify;
//   σ = median |(r[k−1] − 2 r[k]) + r[k+1]| / (0.6745 √6)   (median: the middle value, or the
//   mean (a + b) / 2 of the middle two)
//
// asin and atan2 are the C library's, as numpy's float64 loops call them where the CPU has no
// AVX-512 (numpy's own AVX-512 versions may differ in the last bit: a ring or an order then
// changes only for a return exactly at a bin edge or an azimuth tie).
#ifndef BIMCAP_RASTER_RANGE_NOISE_H_
#define BIMCAP_RASTER_RANGE_NOISE_H_

#include <cstdint>
#include <optional>

namespace bimcap::raster {

// `points` (count, 3) row-major float64 (m). σ in metres, or nothing when fewer than 100 triples
// qualify (or fewer than 3 returns are kept).
std::optional<double> ScanRangeNoise(const double* points, int64_t count, double ring_bin_deg,
                                     double max_step_deg);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_RANGE_NOISE_H_
