#include "bimcap/raster/descriptor_split.h"

#include <cstddef>
#include <vector>

namespace bimcap::raster {

int64_t HighBitLastOrder(const uint8_t* d, int64_t rows, int64_t cols, int64_t* order) {
  std::vector<bool> high(static_cast<size_t>(rows));
  int64_t low = 0;
  for (int64_t i = 0; i < rows; ++i) {
    uint8_t any = 0;
    for (int64_t j = 0; j < cols; ++j) any |= d[i * cols + j];
    high[i] = (any & 0x80) != 0;
    if (!high[i]) order[low++] = i;
  }
  int64_t next = low;
  for (int64_t i = 0; i < rows; ++i) {
    if (high[i]) order[next++] = i;
  }
  return low;
}

void SplitDescriptors(const uint8_t* d, int64_t rows, int64_t cols, const int64_t* order,
                      int64_t first, uint8_t* d_ordered, uint8_t* lo, int8_t* lo_t, uint8_t* hi,
                      int8_t* hi_t) {
  const int64_t num_hi = rows - first;
  for (int64_t i = 0; i < rows; ++i) {
    const uint8_t* src = d + order[i] * cols;
    uint8_t* out = d_ordered + i * cols;
    uint8_t* low = lo + i * cols;
    for (int64_t j = 0; j < cols; ++j) {
      out[j] = src[j];
      low[j] = static_cast<uint8_t>(src[j] & 0x7F);
      lo_t[j * rows + i] = static_cast<int8_t>(src[j] & 0x7F);
    }
    if (i >= first) {
      const int64_t r = i - first;
      for (int64_t j = 0; j < cols; ++j) {
        hi[r * cols + j] = static_cast<uint8_t>(src[j] >> 7);
        hi_t[j * num_hi + r] = static_cast<int8_t>(src[j] >> 7);
      }
    }
  }
}

}  // namespace bimcap::raster
