#include "bimcap/raster/point_neighbours.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "bimcap/raster/k_best.h"

namespace bimcap::raster {

namespace {

constexpr double kMaxCells = 1099511627776.0;  // 2^40

using Cell = std::array<int64_t, 3>;

// The cube of a point: floor(p / cell) per axis.
Cell CellOf(const double* p, double cell) {
  return {static_cast<int64_t>(std::floor(p[0] / cell)),
          static_cast<int64_t>(std::floor(p[1] / cell)),
          static_cast<int64_t>(std::floor(p[2] / cell))};
}

uint64_t Hash(const Cell& c) {
  uint64_t h = static_cast<uint64_t>(c[0]) * 0x9E3779B97F4A7C15ULL;
  h ^= static_cast<uint64_t>(c[1]) * 0xC2B2AE3D27D4EB4FULL + (h << 6) + (h >> 2);
  h ^= static_cast<uint64_t>(c[2]) * 0x165667B19E3779F9ULL + (h << 6) + (h >> 2);
  return h ^ (h >> 29);
}

// The occupied cubes: each one's points (indices, ascending) contiguous in `order`, found by an
// open-addressing hash table.
class Grid {
 public:
  Grid(const double* points, int64_t n, double cell) : order_(static_cast<size_t>(n)) {
    std::vector<Cell> cells(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) cells[i] = CellOf(points + 3 * i, cell);
    std::iota(order_.begin(), order_.end(), int64_t{0});
    std::stable_sort(order_.begin(), order_.end(),
                     [&](int64_t a, int64_t b) { return cells[a] < cells[b]; });
    size_t slots = 16;
    while (slots < 2 * static_cast<size_t>(n)) slots *= 2;
    mask_ = slots - 1;
    table_.assign(slots, Entry{});
    for (int64_t i = 0; i < n;) {
      int64_t j = i + 1;
      while (j < n && cells[order_[j]] == cells[order_[i]]) ++j;
      const Cell& c = cells[order_[i]];
      size_t s = Hash(c) & mask_;
      while (table_[s].end != 0) s = (s + 1) & mask_;
      table_[s] = Entry{c, i, j};
      i = j;
    }
  }

  // The points of cube c as [begin, end) in order(); begin == end when it holds none.
  std::pair<int64_t, int64_t> Find(const Cell& c) const {
    for (size_t s = Hash(c) & mask_;; s = (s + 1) & mask_) {
      const Entry& e = table_[s];
      if (e.end == 0) return {0, 0};
      if (e.cell == c) return {e.begin, e.end};
    }
  }

  const std::vector<int64_t>& order() const { return order_; }

 private:
  struct Entry {
    Cell cell{};
    int64_t begin = 0;
    int64_t end = 0;  // 0: an empty slot (an occupied cube ends after its first point)
  };
  std::vector<int64_t> order_;
  std::vector<Entry> table_;
  size_t mask_ = 0;
};

// cKDTree's squared distance: each square rounded, summed in axis order from 0.
inline double SquaredDistance(const double* x, const double* p) {
  const double d0 = x[0] - p[0], d1 = x[1] - p[1], d2 = x[2] - p[2];
  double d = 0.0;
  d += d0 * d0;
  d += d1 * d1;
  d += d2 * d2;
  return d;
}

void CheckCoordinates(const double* p, int64_t count, double cell, const char* field) {
  for (int64_t i = 0; i < 3 * count; ++i) {
    if (!std::isfinite(p[i]) || std::fabs(p[i] / cell) > kMaxCells) {
      throw RasterError(field, "row " + std::to_string(i / 3) +
                                   " has a coordinate that is not finite or beyond 2^40 cells");
    }
  }
}

}  // namespace

void NearestPoints(const double* points, int64_t n, const double* queries, int64_t num_queries,
                   int k, double cell, int64_t* nearest) {
  if (k < 1 || k > n) {
    throw RasterError("k", "must be in [1, " + std::to_string(n) + "], got " + std::to_string(k));
  }
  if (!std::isfinite(cell) || !(cell > 0.0)) {
    throw RasterError("cell", "must be finite and > 0, got " + std::to_string(cell));
  }
  CheckCoordinates(points, n, cell, "points");
  CheckCoordinates(queries, num_queries, cell, "queries");
  const Grid grid(points, n, cell);
  const std::vector<int64_t>& order = grid.order();
  // A point of cube c lies in [c·cell, (c + 1)·cell] up to the rounding of p / cell: the boxes
  // are widened by `slack` so that their distances stay lower bounds.
  const double slack = 1e-9 * cell;
  KBest best(k);
  for (int64_t q = 0; q < num_queries; ++q) {
    const double* x = queries + 3 * q;
    const Cell own = CellOf(x, cell);
    best.Clear();
    for (int64_t r = 0;; ++r) {
      const double side = static_cast<double>(2 * r + 1);
      if (side * side * side > 8.0 * static_cast<double>(n) + 64.0) {
        // the shells would visit more cubes than there are points (points far apart): every
        // point instead
        best.Clear();
        for (int64_t j = 0; j < n; ++j) best.Offer(SquaredDistance(x, points + 3 * j), j);
        break;
      }
      for (int64_t dx = -r; dx <= r; ++dx) {
        for (int64_t dy = -r; dy <= r; ++dy) {
          const bool inner = std::abs(dx) < r && std::abs(dy) < r;
          // in the shell of radius r: |dz| = r, or any dz when |dx| or |dy| = r
          for (int64_t dz = -r; dz <= r; dz += (inner && r > 0) ? 2 * r : 1) {
            const Cell c{own[0] + dx, own[1] + dy, own[2] + dz};
            double lower = 0.0;
            for (int a = 0; a < 3; ++a) {
              const double lo = static_cast<double>(c[a]) * cell - slack;
              const double hi = static_cast<double>(c[a] + 1) * cell + slack;
              const double gap = x[a] < lo ? lo - x[a] : (x[a] > hi ? x[a] - hi : 0.0);
              lower += gap * gap;
            }
            if (best.full() && lower > best.worst()) continue;
            const auto [begin, end] = grid.Find(c);
            for (int64_t i = begin; i < end; ++i) {
              best.Offer(SquaredDistance(x, points + 3 * order[i]), order[i]);
            }
          }
        }
      }
      // every cube beyond shell r is at least r cells away along some axis
      const double reach = static_cast<double>(r) * cell - slack;
      if (best.full() && reach > 0.0 && reach * reach > best.worst()) break;
    }
    best.Write(nearest + q * k);
  }
}

}  // namespace bimcap::raster
