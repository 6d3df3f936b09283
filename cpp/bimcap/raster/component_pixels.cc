#include "bimcap/raster/component_pixels.h"

#include <string>

namespace bimcap::raster {

int64_t ComponentStarts(const int32_t* labels, int64_t size, int64_t count, int64_t* starts) {
  if (count < 1) throw RasterError("count", "must be >= 1, got " + std::to_string(count));
  for (int64_t c = 0; c <= count; ++c) starts[c] = 0;
  for (int64_t i = 0; i < size; ++i) {
    const int32_t c = labels[i];
    if (c < 0 || c >= count) {
      throw RasterError("labels", "label " + std::to_string(c) + " at " + std::to_string(i) +
                                      " is outside [0, " + std::to_string(count) + ")");
    }
    if (c > 0) ++starts[c + 1];
  }
  for (int64_t c = 1; c <= count; ++c) starts[c] += starts[c - 1];
  return starts[count];
}

void ComponentPixels(const int32_t* labels, int64_t size, int64_t count, const int64_t* starts,
                     int64_t* pixels) {
  std::vector<int64_t> next(starts, starts + count);
  for (int64_t i = 0; i < size; ++i) {
    const int32_t c = labels[i];
    if (c > 0) pixels[next[c]++] = i;
  }
}

}  // namespace bimcap::raster
