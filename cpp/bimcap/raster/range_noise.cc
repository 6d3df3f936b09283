#include "bimcap/raster/range_noise.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {
namespace {

constexpr double kDegreesPerRadian = 180.0 / 3.14159265358979323846;  // numpy's rad2deg factor

// np.median of a[0 … n − 1] (n >= 1; reorders a).
double Median(std::vector<double>* a) {
  const size_t n = a->size(), half = n / 2;
  std::nth_element(a->begin(), a->begin() + half, a->end());
  const double upper = (*a)[half];
  if (n % 2 == 1) return upper;
  const double lower = *std::max_element(a->begin(), a->begin() + half);
  return (lower + upper) / 2.0;
}

// σ of the returns in `order` (sorted by ring, then azimuth): see the header.
std::optional<double> Noise(const std::vector<int64_t>& order, const std::vector<int64_t>& ring,
                            const std::vector<double>& azimuth, const std::vector<double>& range,
                            double max_step_deg) {
  const auto n = static_cast<int64_t>(order.size());
  std::vector<double> second;
  for (int64_t k = 1; k + 1 < n; ++k) {
    const int64_t p = order[k - 1], c = order[k], q = order[k + 1];
    if (ring[c] != ring[p] || ring[c] != ring[q]) continue;
    const double step_a = azimuth[c] - azimuth[p], step_b = azimuth[q] - azimuth[c];
    if (!(step_a < max_step_deg && step_b < max_step_deg &&
          std::fabs(step_a - step_b) < 0.1 * max_step_deg)) {
      continue;
    }
    second.push_back(std::fabs(range[p] - 2.0 * range[c] + range[q]));
  }
  if (second.size() < 100) return std::nullopt;
  return Median(&second) / (0.6745 * std::sqrt(6.0));
}

}  // namespace

std::optional<double> ScanRangeNoise(const double* points, int64_t count, double ring_bin_deg,
                                     double max_step_deg) {
  if (!(ring_bin_deg > 0.0) || !std::isfinite(ring_bin_deg)) {
    throw RasterError("ring_bin_deg",
                      "must be > 0 and finite, got " + std::to_string(ring_bin_deg));
  }
  if (count < 3) return std::nullopt;
  std::vector<double> range, azimuth;
  std::vector<int64_t> ring;
  range.reserve(static_cast<size_t>(count));
  azimuth.reserve(static_cast<size_t>(count));
  ring.reserve(static_cast<size_t>(count));
  for (int64_t i = 0; i < count; ++i) {
    const double x = points[3 * i], y = points[3 * i + 1], z = points[3 * i + 2];
    const double r = std::sqrt(x * x + y * y + z * z);
    if (!(std::isfinite(r) && r > 0)) continue;
    const double s = std::min(std::max(z / r, -1.0), 1.0);
    const double elevation = std::asin(s) * kDegreesPerRadian;
    range.push_back(r);
    azimuth.push_back(std::atan2(y, x) * kDegreesPerRadian);
    ring.push_back(static_cast<int64_t>(std::nearbyint(elevation / ring_bin_deg)));
  }
  const auto n = static_cast<int64_t>(range.size());
  if (n < 3) return std::nullopt;
  // sorted by (ring, azimuth, position): the positions grouped by ring in input order (a
  // counting sort), then each ring's sorted by azimuth, stably (a scan's rings usually come in
  // azimuth order already, or in two runs around ±180°)
  const auto [ring_lo, ring_hi] = std::minmax_element(ring.begin(), ring.end());
  const int64_t first_ring = *ring_lo, num_rings = *ring_hi - *ring_lo + 1;
  if (num_rings > n) {  // rings narrower than the returns are many: one sort
    std::vector<int64_t> all(static_cast<size_t>(n));
    std::iota(all.begin(), all.end(), int64_t{0});
    std::stable_sort(all.begin(), all.end(), [&](int64_t a, int64_t b) {
      return ring[a] != ring[b] ? ring[a] < ring[b] : azimuth[a] < azimuth[b];
    });
    return Noise(all, ring, azimuth, range, max_step_deg);
  }
  std::vector<int64_t> order(static_cast<size_t>(n));
  std::vector<int64_t> start(static_cast<size_t>(num_rings) + 1, 0);
  for (const int64_t k : ring) ++start[k - first_ring + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  {
    std::vector<int64_t> next(start.begin(), start.end() - 1);
    for (int64_t i = 0; i < n; ++i) order[next[ring[i] - first_ring]++] = i;
  }
  const auto by_azimuth = [&](int64_t a, int64_t b) { return azimuth[a] < azimuth[b]; };
  for (int64_t k = 0; k < num_rings; ++k) {
    if (start[k] == start[k + 1]) continue;
    const auto first = order.begin() + start[k], last = order.begin() + start[k + 1];
    if (!std::is_sorted(first, last, by_azimuth)) std::stable_sort(first, last, by_azimuth);
  }
  return Noise(order, ring, azimuth, range, max_step_deg);
}

}  // namespace bimcap::raster
