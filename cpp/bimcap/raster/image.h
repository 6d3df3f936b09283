// A mutable, row-major view of a dense (rows, cols) single-channel image: the pixel at row v,
// column u is data[v * cols + u]. The caller owns the memory.
#ifndef BIMCAP_RASTER_IMAGE_H_
#define BIMCAP_RASTER_IMAGE_H_

#include <cstdint>

namespace bimcap::raster {

template <typename T>
struct ImageRef {
  T* data = nullptr;
  int64_t rows = 0;
  int64_t cols = 0;

  T& at(int64_t v, int64_t u) const { return data[v * cols + u]; }
};

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_IMAGE_H_
