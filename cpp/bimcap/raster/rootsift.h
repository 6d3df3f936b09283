// OpenCV's SIFT descriptors as RootSIFT scaled like COLMAP's (bimcap.features.sift.
// _extract_opencv), in numpy's float64 arithmetic bit for bit, one row at a time:
//
//   s = Σ d_j                      (numpy's pairwise sum: 8 partial sums, then a tree)
//   r_j = clip(rint(sqrt(d_j / max(s, 1e-12)) · 512), 0, 255)     (rint: halves to even)
//
// d_j the float32 values widened to float64; each operation rounded on its own. (OpenCV's SIFT
// descriptors are whole numbers below 256, so their sum is exact in any order.)
#ifndef BIMCAP_RASTER_ROOTSIFT_H_
#define BIMCAP_RASTER_ROOTSIFT_H_

#include <cstdint>

namespace bimcap::raster {

// `desc` (rows, cols) row-major float32 → `out` (rows, cols) uint8.
void RootSiftU8(const float* desc, int64_t rows, int64_t cols, uint8_t* out);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_ROOTSIFT_H_
