// The pixels of each connected component of a label image (cv2.connectedComponents' labels,
// 0 = background), grouped by component, row-major inside each: the planar smoothing's regions
// (bimcap.fusion.completion.smooth_planar_regions), what numpy gave as
//
//   flat = flatnonzero(labels);  order = argsort(labels[flat], kind="stable")
//   pixels = flat[order];        starts = searchsorted(labels[flat][order], arange(count + 1))
//
// here by a counting sort (integers only: the same arrays exactly). Component c's pixels are
// pixels[starts[c] … starts[c + 1]) (starts[0] = starts[1] = 0: the background is left out).
#ifndef BIMCAP_RASTER_COMPONENT_PIXELS_H_
#define BIMCAP_RASTER_COMPONENT_PIXELS_H_

#include <cstdint>
#include <vector>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// `starts` (count + 1) and the number of foreground pixels of `labels` (size); throws
// RasterError ("labels") for a label outside [0, count), ("count") for count < 1.
int64_t ComponentStarts(const int32_t* labels, int64_t size, int64_t count, int64_t* starts);

// Fills `pixels` (as many as ComponentStarts returned) from `starts` (left unchanged).
void ComponentPixels(const int32_t* labels, int64_t size, int64_t count, const int64_t* starts,
                     int64_t* pixels);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_COMPONENT_PIXELS_H_
