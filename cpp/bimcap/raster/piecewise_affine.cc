#include "bimcap/raster/piecewise_affine.h"

#include <cmath>
#include <string>

namespace bimcap::raster {
namespace {

// np.maximum(a, b) for doubles: a NaN a propagates, and of two equal values (−0 and +0) the
// second is kept, as numpy's loops do (np.maximum(-0.0, 0.0) is +0.0).
inline double NumpyMaximum(double a, double b) { return (a > b || std::isnan(a)) ? a : b; }

template <AffineValue kValue>
void Evaluate(const ImageRef<const int32_t>& ids, const double* c0, const double* c1,
              const double* c2, int64_t count, const ImageRef<float>& out) {
  for (int64_t v = 0; v < ids.rows; ++v) {
    const int32_t* id_row = ids.data + v * ids.cols;
    float* out_row = out.data + v * out.cols;
    const double row = static_cast<double>(v);
    for (int64_t u = 0; u < ids.cols; ++u) {
      const int32_t k = id_row[u];
      if (k < 0 || k >= count) {
        throw RasterError("tri_id", "id " + std::to_string(k) + " at row " + std::to_string(v) +
                                        ", column " + std::to_string(u) + " is outside [0, " +
                                        std::to_string(count) + ")");
      }
      double f = c0[k] * static_cast<double>(u);
      f += c1[k] * row;
      f += c2[k];
      double z;
      if constexpr (kValue == AffineValue::kInverseDepth) {
        z = f > 0 ? 1.0 / NumpyMaximum(f, 1e-12) : 0.0;
      } else {
        z = NumpyMaximum(f, 0.0);
      }
      out_row[u] = static_cast<float>(z);
    }
  }
}

}  // namespace

void EvaluatePiecewiseAffine(const ImageRef<const int32_t>& ids, const double* coef, int64_t count,
                             AffineValue value, const ImageRef<float>& out) {
  if (ids.rows != out.rows || ids.cols != out.cols) {
    throw RasterError("tri_id", "id image (" + std::to_string(ids.rows) + ", " +
                                    std::to_string(ids.cols) + ") and output (" +
                                    std::to_string(out.rows) + ", " + std::to_string(out.cols) +
                                    ") differ");
  }
  if (count <= 0) throw RasterError("coef", "the table needs at least column 0 (no triangle)");
  const double* c0 = coef;
  const double* c1 = coef + count;
  const double* c2 = coef + 2 * count;
  if (value == AffineValue::kInverseDepth) {
    Evaluate<AffineValue::kInverseDepth>(ids, c0, c1, c2, count, out);
  } else {
    Evaluate<AffineValue::kDepth>(ids, c0, c1, c2, count, out);
  }
}

}  // namespace bimcap::raster
