#include "bimcap/raster/similarity_top2.h"

#include <algorithm>
#include <limits>

// The loops below are integer max / min only, which compilers vectorise; on x86-64 with GCC or
// Clang copies for AVX2 and AVX-512 are picked at load time (two and four times as wide as the
// SSE2 baseline; AVX-512 ~1.2× cheaper than AVX2 on a 1040 × 1020 matrix, 2026-11-28).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(__AVX2__)
#define BIMCAP_TOP2_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define BIMCAP_TOP2_CLONES
#endif

namespace bimcap::raster {
namespace {

constexpr int32_t kLow = std::numeric_limits<int32_t>::min();

// The columns' top two (c1 >= c2, equal values counted twice) merged with four rows' values, and
// each row's largest value: one pass with no branch (the pointers never alias).
BIMCAP_TOP2_CLONES void FourRows(const int32_t* __restrict r0, const int32_t* __restrict r1,
                                 const int32_t* __restrict r2, const int32_t* __restrict r3,
                                 int64_t cols, int32_t* __restrict c1, int32_t* __restrict c2,
                                 int32_t* __restrict best) {
  int32_t b0 = kLow, b1 = kLow, b2 = kLow, b3 = kLow;
  for (int64_t j = 0; j < cols; ++j) {
    const int32_t v0 = r0[j], v1 = r1[j], v2 = r2[j], v3 = r3[j];
    b0 = std::max(b0, v0);
    b1 = std::max(b1, v1);
    b2 = std::max(b2, v2);
    b3 = std::max(b3, v3);
    const int32_t hi01 = std::max(v0, v1), lo01 = std::min(v0, v1);
    const int32_t hi23 = std::max(v2, v3), lo23 = std::min(v2, v3);
    const int32_t top = std::max(hi01, hi23);
    const int32_t second = std::max(std::min(hi01, hi23), std::max(lo01, lo23));
    c2[j] = std::max(std::max(c2[j], second), std::min(c1[j], top));
    c1[j] = std::max(c1[j], top);
  }
  best[0] = b0;
  best[1] = b1;
  best[2] = b2;
  best[3] = b3;
}

BIMCAP_TOP2_CLONES void OneRow(const int32_t* __restrict r, int64_t cols, int32_t* __restrict c1,
                               int32_t* __restrict c2, int32_t* __restrict best) {
  int32_t b = kLow;
  for (int64_t j = 0; j < cols; ++j) {
    const int32_t v = r[j];
    b = std::max(b, v);
    c2[j] = std::max(c2[j], std::min(c1[j], v));
    c1[j] = std::max(c1[j], v);
  }
  *best = b;
}

BIMCAP_TOP2_CLONES int32_t MaxOf(const int32_t* __restrict r, int64_t n) {
  int32_t b = kLow;
  for (int64_t j = 0; j < n; ++j) b = std::max(b, r[j]);
  return b;
}

}  // namespace

void SimilarityTop2(const int32_t* sim, int64_t rows, int64_t cols, int64_t* row_best,
                    int32_t* row_s1, int32_t* row_s2, int32_t* col_s1, int32_t* col_s2) {
  std::fill(col_s1, col_s1 + cols, kLow);
  std::fill(col_s2, col_s2 + cols, kLow);
  for (int64_t i = 0; i < rows; i += 4) {
    const int32_t* r = sim + i * cols;
    const int64_t n = std::min<int64_t>(4, rows - i);
    if (n == 4) {
      FourRows(r, r + cols, r + 2 * cols, r + 3 * cols, cols, col_s1, col_s2, row_s1 + i);
    } else {
      for (int64_t k = 0; k < n; ++k) OneRow(r + k * cols, cols, col_s1, col_s2, row_s1 + i + k);
    }
    // The rows are still in the cache: the first column of each one's largest value, then the
    // largest of the others.
    for (int64_t k = i; k < i + n; ++k) {
      const int32_t* row = sim + k * cols;
      int64_t at = 0;
      while (row[at] != row_s1[k]) ++at;
      row_best[k] = at;
      row_s2[k] = std::max(MaxOf(row, at), MaxOf(row + at + 1, cols - at - 1));
    }
  }
}

}  // namespace bimcap::raster
