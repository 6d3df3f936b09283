#include "bimcap/raster/near_region.h"

#include <algorithm>
#include <string>

namespace bimcap::raster {

std::vector<int64_t> NearRegion(const ImageRef<const int32_t>& region_id, int32_t k, int reach,
                                const int64_t* at, int64_t count, bool rows_ascending, int64_t top,
                                int64_t stop) {
  if (reach < 0) throw RasterError("reach", "must be >= 0, got " + std::to_string(reach));
  const int64_t h = region_id.rows, w = region_id.cols;
  std::vector<int64_t> hits;
  top = std::max<int64_t>(top, 0);
  stop = std::min<int64_t>(stop, h);
  if (top >= stop) return hits;
  const int64_t lo_row = std::max<int64_t>(top - reach, 0);
  const int64_t hi_row = std::min<int64_t>(stop + reach, h);  // rows [lo_row, hi_row) can be near
  int64_t begin = 0, end = count;
  if (rows_ascending) {
    begin = std::lower_bound(at, at + count, lo_row * w) - at;
    end = std::lower_bound(at, at + count, hi_row * w) - at;
  }
  if (begin >= end) return hits;
  // counts of region k's pixels in rows [top, top + y) and columns [0, x): each window's count
  // from four of them
  const int64_t band = stop - top;
  std::vector<int32_t> table(static_cast<size_t>((band + 1) * (w + 1)), 0);
  for (int64_t y = 0; y < band; ++y) {
    const int32_t* row = region_id.data + (top + y) * w;
    int32_t* above = table.data() + y * (w + 1);
    int32_t* below = above + (w + 1);
    int32_t run = 0;
    for (int64_t x = 0; x < w; ++x) {
      run += row[x] == k;
      below[x + 1] = above[x + 1] + run;
    }
  }
  const auto count_at = [&](int64_t y, int64_t x) { return table[y * (w + 1) + x]; };
  CheckPixelIndices(at, begin, end, h * w, "at");
  for (int64_t i = begin; i < end; ++i) {
    const int64_t v = at[i] / w, u = at[i] % w;
    if (v < lo_row || v >= hi_row) continue;
    const int64_t y0 = std::max(v - reach, top) - top, y1 = std::min(v + reach + 1, stop) - top;
    const int64_t x0 = std::max<int64_t>(u - reach, 0), x1 = std::min<int64_t>(u + reach + 1, w);
    if (count_at(y1, x1) - count_at(y0, x1) - count_at(y1, x0) + count_at(y0, x0) > 0) {
      hits.push_back(i);
    }
  }
  return hits;
}

}  // namespace bimcap::raster
