// Grey levels of an RGB image for the feature extractor (bimcap.features.sift.to_gray_u8), in
// numpy's arithmetic bit for bit:
//
//   g = rint(r · 0.299 + g · 0.587 + b · 0.114)   clipped to [0, 255]   (BT.601 luma)
//
// Each product and the two sums (left to right) are float64, each rounded on its own; rint
// rounds halves to even (the default rounding mode). The file is compiled with
// -ffp-contract=off (no fused multiply-add).
#ifndef BIMCAP_RASTER_GRAY_H_
#define BIMCAP_RASTER_GRAY_H_

#include <cstdint>

namespace bimcap::raster {

// gray[i] from rgb[3 i], rgb[3 i + 1], rgb[3 i + 2] for i < pixels.
void RgbToGray(const uint8_t* rgb, int64_t pixels, uint8_t* gray);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_GRAY_H_
