#include "bimcap/raster/plane_scores.h"

#include <cmath>
#include <vector>

namespace bimcap::raster {

namespace {

// One row of the block: count[j] += |t[j] + offsets[j]| < thr (and |a[j]| > cos_n). The counts
// are doubles (whole numbers, exact up to 2⁵³ rows): x86-64's baseline SSE2 has no 64-bit
// integer comparison masks, so int64 counts would keep the loop from vectorising.
inline void CountRow(const double* __restrict t, const double* __restrict offsets, double thr,
                     int64_t cols, double* __restrict count) {
  for (int64_t j = 0; j < cols; ++j) {
    count[j] += std::fabs(t[j] + offsets[j]) < thr ? 1.0 : 0.0;
  }
}

inline void CountRowAgreeing(const double* __restrict t, const double* __restrict a,
                             const double* __restrict offsets, double thr, double cos_n,
                             int64_t cols, double* __restrict count) {
  for (int64_t j = 0; j < cols; ++j) {
    count[j] += (std::fabs(t[j] + offsets[j]) < thr) & (std::fabs(a[j]) > cos_n) ? 1.0 : 0.0;
  }
}

}  // namespace

// x86-64 with GCC or Clang: an AVX2 clone picked at load time where the CPU has it (the same
// additions and comparisons, each rounded on its own: the same counts on every path).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("avx2", "default")))
#endif
void AddPlaneScores(const double* products, const double* agree, const double* offsets,
                    const double* thresholds, int64_t rows, int64_t cols, double cos_n,
                    int64_t* score) {
  // the block's per-column counts, row by row (the tables' order in memory)
  std::vector<double> count(static_cast<size_t>(cols), 0.0);
  for (int64_t i = 0; i < rows; ++i) {
    if (agree == nullptr) {
      CountRow(products + i * cols, offsets, thresholds[i], cols, count.data());
    } else {
      CountRowAgreeing(products + i * cols, agree + i * cols, offsets, thresholds[i], cos_n, cols,
                       count.data());
    }
  }
  for (int64_t j = 0; j < cols; ++j) score[j] += static_cast<int64_t>(count[j]);
}

}  // namespace bimcap::raster
