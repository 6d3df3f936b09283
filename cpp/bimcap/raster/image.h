// A mutable, row-major view of a dense (rows, cols) single-channel image: the pixel at row v,
// column u is data[v * cols + u]. The caller owns the memory.
#ifndef BIMCAP_RASTER_IMAGE_H_
#define BIMCAP_RASTER_IMAGE_H_

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <limits>

namespace bimcap::raster {

// numpy's float64 → float32 cast (to nearest, ties to even): beyond ±FLT_MAX a value rounds to
// ±FLT_MAX up to half a unit above it, else to ±inf (a plain static_cast is undefined there).
inline float RoundToFloat32(double x) {
  constexpr double kHalfUlpAboveMax = static_cast<double>(FLT_MAX) + 0x1p103;
  const double a = std::fabs(x);
  if (!(a > static_cast<double>(FLT_MAX))) return static_cast<float>(x);  // also NaN
  const float big = a >= kHalfUlpAboveMax ? std::numeric_limits<float>::infinity() : FLT_MAX;
  return std::signbit(x) ? -big : big;
}

template <typename T>
struct ImageRef {
  T* data = nullptr;
  int64_t rows = 0;
  int64_t cols = 0;

  T& at(int64_t v, int64_t u) const { return data[v * cols + u]; }
};

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_IMAGE_H_
