#include "bimcap/raster/gray.h"

namespace bimcap::raster {

namespace {
// x + 1.5 · 2⁵² − 1.5 · 2⁵² is x rounded to an integer in the current rounding mode (to nearest,
// halves to even: numpy's rint) for |x| < 2⁵¹, without a library call, so the loop vectorises.
constexpr double kRoundMagic = 6755399441055744.0;
}  // namespace

void RgbToGray(const uint8_t* rgb, int64_t pixels, uint8_t* gray) {
  for (int64_t i = 0; i < pixels; ++i) {
    const uint8_t* p = rgb + 3 * i;
    const double sum = static_cast<double>(p[0]) * 0.299 + static_cast<double>(p[1]) * 0.587 +
                       static_cast<double>(p[2]) * 0.114;  // in [0, 255]: no clipping needed
    const double shifted = sum + kRoundMagic;              // not folded: no -ffast-math here
    gray[i] = static_cast<uint8_t>(shifted - kRoundMagic);
  }
}

}  // namespace bimcap::raster
