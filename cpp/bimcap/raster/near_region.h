// Which of a list of pixels lie within a square window of a region's pixels
// (bimcap.segmentation.geometric._near_region: the pixels that cv2.dilate(region_id == k,
// ones((2 reach + 1, 2 reach + 1))) covers, read at the listed pixels):
//
//   near(p) = some pixel q of the image with region_id[q] = k, |row(q) − row(p)| <= reach and
//             |col(q) − col(p)| <= reach
//
// Only the rows [top − reach, stop + reach) can be near when the region's pixels lie in rows
// [top, stop); the listed pixels there are found by binary search when their rows never
// decrease, else each is tested.
#ifndef BIMCAP_RASTER_NEAR_REGION_H_
#define BIMCAP_RASTER_NEAR_REGION_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/image.h"

namespace bimcap::raster {

// Positions (ascending) in `at` (count,) (raveled pixel indices of `region_id`) of the pixels
// near region k. `rows_ascending`: the pixels' rows never decrease along `at` (not checked: the
// entries within reach are then found by binary search, and an `at` out of order gives some
// of them). `top`, `stop`: rows that hold every pixel of region k (clipped to the image).
// Throws RasterError ("at") for an index outside the image among the entries read, ("reach")
// for reach < 0.
std::vector<int64_t> NearRegion(const ImageRef<const int32_t>& region_id, int32_t k, int reach,
                                const int64_t* at, int64_t count, bool rows_ascending, int64_t top,
                                int64_t stop);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_NEAR_REGION_H_
