#include "bimcap/raster/plane_scores.h"

#include <cmath>
#include <vector>

namespace bimcap::raster {

// The counts are doubles (whole numbers, exact up to 2⁵³ rows): x86-64 has no 64-bit integer
// comparison masks before AVX-512, so int64 counts would keep the loops from vectorising. On
// x86-64 with GCC or Clang an FMA clone (256-bit vectors, fused multiply-add in hardware) is
// picked at load time where the CPU has it; both clones form the same numbers.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("fma", "default")))
#endif
void AddPlaneScores(const double* points, const double* normals, const double* planes,
                    const double* offsets, const double* thresholds, int64_t rows,
                    int64_t hypotheses, double cos_n, int64_t* score) {
  // the hypotheses' components side by side, so that the inner loop runs over them
  const auto m = static_cast<size_t>(hypotheses);
  std::vector<double> h0(m), h1(m), h2(m), count(m, 0.0);
  for (size_t j = 0; j < m; ++j) {
    h0[j] = planes[3 * j];
    h1[j] = planes[3 * j + 1];
    h2[j] = planes[3 * j + 2];
  }
  const double* __restrict a0 = h0.data();
  const double* __restrict a1 = h1.data();
  const double* __restrict a2 = h2.data();
  const double* __restrict d = offsets;
  double* __restrict c = count.data();
  for (int64_t i = 0; i < rows; ++i) {
    const double p0 = points[3 * i], p1 = points[3 * i + 1], p2 = points[3 * i + 2];
    const double thr = thresholds[i];
    if (normals == nullptr) {
      for (int64_t j = 0; j < hypotheses; ++j) {
        const double t = std::fma(p2, a2[j], std::fma(p1, a1[j], p0 * a0[j]));
        c[j] += std::fabs(t + d[j]) < thr ? 1.0 : 0.0;
      }
    } else {
      const double q0 = normals[3 * i], q1 = normals[3 * i + 1], q2 = normals[3 * i + 2];
      for (int64_t j = 0; j < hypotheses; ++j) {
        const double t = std::fma(p2, a2[j], std::fma(p1, a1[j], p0 * a0[j]));
        const double a = std::fma(q2, a2[j], std::fma(q1, a1[j], q0 * a0[j]));
        c[j] += (std::fabs(t + d[j]) < thr) & (std::fabs(a) > cos_n) ? 1.0 : 0.0;
      }
    }
  }
  for (int64_t j = 0; j < hypotheses; ++j) score[j] += static_cast<int64_t>(c[j]);
}

}  // namespace bimcap::raster
