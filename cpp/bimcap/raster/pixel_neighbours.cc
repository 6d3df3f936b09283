#include "bimcap/raster/pixel_neighbours.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "bimcap/raster/k_best.h"

namespace bimcap::raster {

namespace {

// Offers the pixels of one row (columns cols[begin, end), ascending) at squared row offset dy2:
// outward from x, the nearer of the next left and right pixel first, until the squared column
// offset alone is beyond the k-th.
void ScanRow(const int64_t* cols, int64_t begin, int64_t end, double x, double dy2, KBest& best) {
  int64_t right = std::lower_bound(cols + begin, cols + end, x,
                                   [](int64_t c, double q) { return static_cast<double>(c) < q; }) -
                  cols;
  int64_t left = right - 1;
  while (left >= begin || right < end) {
    const double dx_left = left >= begin ? x - static_cast<double>(cols[left]) : HUGE_VAL;
    const double dx_right = right < end ? static_cast<double>(cols[right]) - x : HUGE_VAL;
    const bool take_left = dx_left <= dx_right;
    const double dx = take_left ? dx_left : dx_right;
    const double dx2 = dx * dx;
    if (best.full() && dx2 > best.worst()) break;  // the other side is no nearer
    best.Offer(dx2 + dy2, take_left ? left-- : right++);
  }
}

}  // namespace

void NearestPixels(const int64_t* row_start, int64_t rows, const int64_t* cols, int64_t n,
                   const double* queries, int64_t num_queries, int k, int64_t* nearest) {
  if (k < 1 || k > n) {
    throw RasterError("k", "must be in [1, " + std::to_string(n) + "], got " + std::to_string(k));
  }
  if (rows < 1 || row_start[0] != 0 || row_start[rows] != n) {
    throw RasterError("row_start", "must rise from 0 to the number of pixels");
  }
  for (int64_t v = 0; v < rows; ++v) {
    if (row_start[v + 1] < row_start[v]) {
      throw RasterError("row_start", "falls at row " + std::to_string(v));
    }
    for (int64_t i = row_start[v] + 1; i < row_start[v + 1]; ++i) {
      if (cols[i] <= cols[i - 1]) {
        throw RasterError("cols", "not ascending in row " + std::to_string(v));
      }
    }
  }
  for (int64_t q = 0; q < 2 * num_queries; ++q) {
    if (!std::isfinite(queries[q])) {
      throw RasterError("queries", "query " + std::to_string(q / 2) + " is not finite");
    }
  }
  KBest best(k);
  for (int64_t q = 0; q < num_queries; ++q) {
    const double x = queries[2 * q], y = queries[2 * q + 1];
    best.Clear();
    // rows below (v <= y) and above (v > y), each direction until the row offset alone is
    // beyond the k-th distance; the nearer of the two next rows first
    const double fy = std::floor(y);
    int64_t down = static_cast<int64_t>(std::clamp(fy, -1.0, static_cast<double>(rows - 1)));
    int64_t up = static_cast<int64_t>(std::clamp(fy + 1.0, 0.0, static_cast<double>(rows)));
    while (down >= 0 || up < rows) {
      const double dy_down = down >= 0 ? y - static_cast<double>(down) : HUGE_VAL;
      const double dy_up = up < rows ? static_cast<double>(up) - y : HUGE_VAL;
      const bool take_down = dy_down <= dy_up;
      const int64_t v = take_down ? down : up;
      const double dy = take_down ? dy_down : dy_up;
      const double dy2 = dy * dy;
      if (best.full() && dy2 > best.worst()) {  // and every row further out in this direction
        if (take_down) {
          down = -1;
        } else {
          up = rows;
        }
        continue;
      }
      ScanRow(cols, row_start[v], row_start[v + 1], x, dy2, best);
      if (take_down) {
        --down;
      } else {
        ++up;
      }
    }
    best.Write(nearest + q * k);
  }
}

}  // namespace bimcap::raster
