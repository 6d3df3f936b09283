// uint8 SIFT descriptors split for exact integer products (bimcap.features.matching._Int8Rows,
// rows reordered as matching._hi_last orders them), in one pass instead of numpy's six:
//
//   order = the rows without a value >= 128, then those with one (each in its order)
//   d' = d[order];  lo = d' & 127;  hi = d'[first:] >> 7 (0 or 1), first = rows without one
//   lo_t = loᵀ, hi_t = hiᵀ (as int8: the right operands of MatMulInteger)
//
// Integers only: the same bytes as the numpy expressions.
#ifndef BIMCAP_RASTER_DESCRIPTOR_SPLIT_H_
#define BIMCAP_RASTER_DESCRIPTOR_SPLIT_H_

#include <cstdint>

namespace bimcap::raster {

// The rows of `d` (rows, cols) row-major without a value >= 128; fills `order` (rows,) with
// them first and the others after, each in ascending order.
int64_t HighBitLastOrder(const uint8_t* d, int64_t rows, int64_t cols, int64_t* order);

// With `order` from HighBitLastOrder and `first` its count: writes d_ordered (rows, cols),
// lo (rows, cols), lo_t (cols, rows), hi (rows − first, cols) and hi_t (cols, rows − first).
void SplitDescriptors(const uint8_t* d, int64_t rows, int64_t cols, const int64_t* order,
                      int64_t first, uint8_t* d_ordered, uint8_t* lo, int8_t* lo_t, uint8_t* hi,
                      int8_t* hi_t);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_DESCRIPTOR_SPLIT_H_
