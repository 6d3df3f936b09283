#include "bimcap/raster/rootsift.h"

#include <cmath>
#include <vector>

namespace bimcap::raster {

namespace {

// numpy's pairwise summation of n contiguous float64 values (npy_pairwise_sum): below 8 values
// a plain sum from 0; up to 128, eight partial sums over strides of 8, added as a tree, then
// the rest; above, the two halves (the first a multiple of 8) summed apart.
double PairwiseSum(const double* a, int64_t n) {
  if (n < 8) {
    double res = 0.0;
    for (int64_t i = 0; i < n; ++i) res += a[i];
    return res;
  }
  if (n <= 128) {
    double r[8];
    for (int j = 0; j < 8; ++j) r[j] = a[j];
    int64_t i = 8;
    for (; i < n - (n % 8); i += 8) {
      for (int j = 0; j < 8; ++j) r[j] += a[i + j];
    }
    double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for (; i < n; ++i) res += a[i];
    return res;
  }
  int64_t n2 = n / 2;
  n2 -= n2 % 8;
  return PairwiseSum(a, n2) + PairwiseSum(a + n2, n - n2);
}

}  // namespace

void RootSiftU8(const float* desc, int64_t rows, int64_t cols, uint8_t* out) {
  std::vector<double> row(static_cast<size_t>(cols));
  for (int64_t i = 0; i < rows; ++i) {
    for (int64_t j = 0; j < cols; ++j) row[j] = static_cast<double>(desc[i * cols + j]);
    const double sum = PairwiseSum(row.data(), cols);
    const double norm = sum > 1e-12 ? sum : 1e-12;  // np.maximum (NaN: propagated below)
    for (int64_t j = 0; j < cols; ++j) {
      const double v = std::nearbyint(std::sqrt(row[j] / (std::isnan(sum) ? sum : norm)) * 512.0);
      out[i * cols + j] = static_cast<uint8_t>(v > 255.0 ? 255.0 : (v > 0.0 ? v : 0.0));
    }
  }
}

}  // namespace bimcap::raster
