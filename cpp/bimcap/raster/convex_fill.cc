#include "bimcap/raster/convex_fill.h"

#include <algorithm>
#include <string>
#include <utility>

namespace bimcap::raster {
namespace {

constexpr int kXyShift = 16;
constexpr int64_t kXyOne = int64_t{1} << kXyShift;
constexpr int64_t kHalf = kXyOne >> 1;

// An arithmetic right shift (floor division by 2^s) of a possibly negative value, as OpenCV's
// `>>` on int64 does with the compilers it is built with.
constexpr int64_t Floor2(int64_t a, int s) { return a >> s; }

// Sets the pixel (u, v) if it lies inside the image.
inline void Put(const ImageRef<int32_t>& image, int64_t u, int64_t v, int32_t value) {
  if (0 <= u && u < image.cols && 0 <= v && v < image.rows) image.at(v, u) = value;
}

// Cohen–Sutherland outcode against [0, right] × [0, bottom].
inline int Outcode(int64_t x, int64_t y, int64_t right, int64_t bottom) {
  return (x < 0) + (x > right) * 2 + (y < 0) * 4 + (y > bottom) * 8;
}

// cv::clipLine(Size2l(width, height), p1, p2): clips the segment to [0, width − 1] ×
// [0, height − 1] in place (one pass: first the rows, then the columns, with integer
// divisions rounding toward zero); false when nothing of it is left.
bool ClipSegment(int64_t width, int64_t height, int64_t& x1, int64_t& y1, int64_t& x2,
                 int64_t& y2) {
  if (width <= 0 || height <= 0) return false;
  const int64_t right = width - 1;
  const int64_t bottom = height - 1;
  int c1 = Outcode(x1, y1, right, bottom);
  int c2 = Outcode(x2, y2, right, bottom);
  if ((c1 & c2) == 0 && (c1 | c2) != 0) {
    if (c1 & 12) {
      const int64_t a = c1 < 8 ? 0 : bottom;
      x1 += (a - y1) * (x2 - x1) / (y2 - y1);
      y1 = a;
      c1 = (x1 < 0) + (x1 > right) * 2;
    }
    if (c2 & 12) {
      const int64_t a = c2 < 8 ? 0 : bottom;
      x2 += (a - y2) * (x2 - x1) / (y2 - y1);
      y2 = a;
      c2 = (x2 < 0) + (x2 > right) * 2;
    }
    if ((c1 & c2) == 0 && (c1 | c2) != 0) {
      if (c1) {
        const int64_t a = c1 == 1 ? 0 : right;
        y1 += (a - x1) * (y2 - y1) / (x2 - x1);
        x1 = a;
        c1 = 0;
      }
      if (c2) {
        const int64_t a = c2 == 1 ? 0 : right;
        y2 += (a - x2) * (y2 - y1) / (x2 - x1);
        x2 = a;
        c2 = 0;
      }
    }
  }
  return (c1 | c2) == 0;
}

// OpenCV's Line2: the 8-connected segment between two 16.16 fixed-point points.
void DrawSegment(const ImageRef<int32_t>& image, int64_t x1, int64_t y1, int64_t x2, int64_t y2,
                 int32_t value) {
  if (!ClipSegment(image.cols * kXyOne, image.rows * kXyOne, x1, y1, x2, y2)) return;
  const int64_t dx = x2 - x1;
  const int64_t dy = y2 - y1;
  const int64_t ax = dx < 0 ? -dx : dx;
  const int64_t ay = dy < 0 ? -dy : dy;
  const bool along_x = ax > ay;
  int64_t x_step = kXyOne;
  int64_t y_step = kXyOne;
  int64_t steps;
  if (along_x) {
    // From the left end; the minor step keeps its sign relative to that direction.
    if (dx < 0) {
      std::swap(x1, x2);
      std::swap(y1, y2);
    }
    y_step = (dx < 0 ? -dy : dy) * kXyOne / (ax | 1);
    steps = Floor2(x2 - x1, kXyShift);
  } else {
    if (dy < 0) {
      std::swap(x1, x2);
      std::swap(y1, y2);
    }
    x_step = (dy < 0 ? -dx : dx) * kXyOne / (ay | 1);
    steps = Floor2(y2 - y1, kXyShift);
  }
  x1 += kHalf;
  y1 += kHalf;
  Put(image, Floor2(x2 + kHalf, kXyShift), Floor2(y2 + kHalf, kXyShift), value);
  // OpenCV keeps the count in an int and casts the coordinates to int; both stay far inside
  // int's range for the image sizes a numpy array can have here (|coordinate| < 2^31 / 2^16).
  if (along_x) {
    int64_t u = Floor2(x1, kXyShift);
    for (; steps >= 0; --steps, ++u, y1 += y_step) Put(image, u, Floor2(y1, kXyShift), value);
  } else {
    int64_t v = Floor2(y1, kXyShift);
    for (; steps >= 0; --steps, ++v, x1 += x_step) Put(image, Floor2(x1, kXyShift), v, value);
  }
}

void CheckShiftAndImage(int shift, const ImageRef<int32_t>& image) {
  // OpenCV draws the outline of integer vertices (shift 0) with its LineIterator instead of
  // Line2; that path is not reproduced.
  if (shift < 1 || shift > kMaxShift) {
    throw RasterError("shift", "must be in [1, 16], got " + std::to_string(shift));
  }
  if (image.rows < 0 || image.cols < 0 || image.rows > kMaxCoordinatePx ||
      image.cols > kMaxCoordinatePx) {
    throw RasterError("image", "sides must be in [0, " + std::to_string(kMaxCoordinatePx) +
                                   "] px, got " + std::to_string(image.rows) + " x " +
                                   std::to_string(image.cols));
  }
}

// Throws RasterError ("corners") naming `what` (built only then) unless every coordinate of
// the `count` vertices lies within ±kMaxCoordinatePx px.
template <typename What>
void CheckVertices(const int32_t* vertices, int count, int shift, const What& what) {
  const int64_t limit = kMaxCoordinatePx << shift;
  for (int i = 0; i < 2 * count; ++i) {
    if (vertices[i] < -limit || vertices[i] > limit) {
      throw RasterError("corners", what() + " has a coordinate " + std::to_string(vertices[i]) +
                                       " / 2^" + std::to_string(shift) + " px beyond ±" +
                                       std::to_string(kMaxCoordinatePx) + " px");
    }
  }
}

struct Edge {
  int idx = 0;          // the vertex the edge currently ends at
  int di = 0;           // +1 (vertex order) or count − 1 (against it)
  int64_t x = -kXyOne;  // 16.16 x at the current row
  int64_t dx = 0;       // 16.16 x step per row
  int64_t ye = 0;       // the row at which the edge ends
};

}  // namespace

void FillConvexPolygon(const ImageRef<int32_t>& image, const int32_t* vertices, int count,
                       int32_t value, int shift) {
  CheckShiftAndImage(shift, image);
  if (count <= 0) return;
  CheckVertices(vertices, count, shift, [] { return std::string("the polygon"); });
  const int up = kXyShift - shift;
  const int64_t delta = (int64_t{1} << shift) >> 1;
  auto vx = [&](int i) { return static_cast<int64_t>(vertices[2 * i]); };
  auto vy = [&](int i) { return static_cast<int64_t>(vertices[2 * i + 1]); };

  // Outline, and the bounding box with the topmost (first of the lowest y) vertex.
  int64_t xmin = vx(0), xmax = vx(0), ymin = vy(0), ymax = vy(0);
  int imin = 0;
  int64_t px0 = vx(count - 1) * (int64_t{1} << up);
  int64_t py0 = vy(count - 1) * (int64_t{1} << up);
  for (int i = 0; i < count; ++i) {
    if (vy(i) < ymin) {
      ymin = vy(i);
      imin = i;
    }
    ymax = std::max(ymax, vy(i));
    xmax = std::max(xmax, vx(i));
    xmin = std::min(xmin, vx(i));
    const int64_t px = vx(i) * (int64_t{1} << up);
    const int64_t py = vy(i) * (int64_t{1} << up);
    DrawSegment(image, px0, py0, px, py, value);
    px0 = px;
    py0 = py;
  }
  xmin = Floor2(xmin + delta, shift);
  xmax = Floor2(xmax + delta, shift);
  ymin = Floor2(ymin + delta, shift);
  ymax = Floor2(ymax + delta, shift);
  if (count < 3 || xmax < 0 || ymax < 0 || xmin >= image.cols || ymin >= image.rows) return;
  ymax = std::min(ymax, image.rows - 1);

  // Interior: two edges from the top vertex, one in each direction round the polygon. `edges`
  // counts the polygon's edges not yet taken; it runs out (< 0) once the walk has gone round.
  Edge edge[2];
  edge[0].idx = edge[1].idx = imin;
  edge[0].ye = edge[1].ye = ymin;
  edge[0].di = 1;
  edge[1].di = count - 1;
  int edges = count;
  int64_t y = ymin;
  do {
    for (Edge& e : edge) {
      if (y < e.ye) continue;
      int idx0 = e.idx;
      int idx = idx0 + e.di;
      if (idx >= count) idx -= count;
      while (edges-- > 0) {
        const int64_t ty = Floor2(vy(idx) + delta, shift);
        if (ty > y) {
          const int64_t xs = vx(idx0) * (int64_t{1} << up);
          const int64_t xe = vx(idx) * (int64_t{1} << up);
          e.ye = ty;
          e.dx = ((xe - xs) * 2 + (ty - y)) / (2 * (ty - y));
          e.x = xs;
          e.idx = idx;
          break;
        }
        idx0 = idx;
        idx += e.di;
        if (idx >= count) idx -= count;
      }
    }
    if (edges < 0) break;
    if (y >= 0) {
      const bool swapped = edge[0].x > edge[1].x;
      const Edge& left = edge[swapped ? 1 : 0];
      const Edge& right = edge[swapped ? 0 : 1];
      int64_t u1 = Floor2(left.x + kHalf, kXyShift);
      int64_t u2 = Floor2(right.x + kHalf, kXyShift);
      if (u2 >= 0 && u1 < image.cols) {
        u1 = std::max<int64_t>(u1, 0);
        u2 = std::min<int64_t>(u2, image.cols - 1);
        int32_t* row = image.data + y * image.cols;
        for (int64_t u = u1; u <= u2; ++u) row[u] = value;
      }
    }
    edge[0].x += edge[0].dx;
    edge[1].x += edge[1].dx;
  } while (++y <= ymax);
}

void FillTriangleIds(const ImageRef<int32_t>& image, const int32_t* corners, const int32_t* ids,
                     int64_t count, int shift) {
  CheckShiftAndImage(shift, image);
  for (int64_t t = 0; t < count; ++t) {
    CheckVertices(corners + 6 * t, 3, shift, [t] { return "triangle " + std::to_string(t); });
  }
  for (int64_t t = 0; t < count; ++t) FillConvexPolygon(image, corners + 6 * t, 3, ids[t], shift);
}

void FillContainingTriangleIds(const ImageRef<int32_t>& image, const int32_t* corners,
                               const int32_t* ids, int64_t count, int shift) {
  CheckShiftAndImage(shift, image);
  for (int64_t t = 0; t < count; ++t) {
    CheckVertices(corners + 6 * t, 3, shift, [t] { return "triangle " + std::to_string(t); });
  }
  const int64_t one = int64_t{1} << shift;
  for (int64_t t = 0; t < count; ++t) {
    const int32_t* c = corners + 6 * t;
    int64_t x[3] = {c[0], c[2], c[4]};
    int64_t y[3] = {c[1], c[3], c[5]};
    const int64_t area2 = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    if (area2 == 0) continue;
    if (area2 < 0) {
      std::swap(x[1], x[2]);
      std::swap(y[1], y[2]);
    }
    // Per edge s -> t: E(p) = a p_x + b p_y + k, and whether E = 0 counts as inside (top-left).
    int64_t a[3], b[3], k[3];
    bool tie[3];
    for (int e = 0; e < 3; ++e) {
      const int f = (e + 1) % 3;
      const int64_t dx = x[f] - x[e], dy = y[f] - y[e];
      a[e] = -dy;
      b[e] = dx;
      k[e] = dy * x[e] - dx * y[e];
      tie[e] = dy < 0 || (dy == 0 && dx > 0);
    }
    // the pixel centres u · 2^shift within the corners' box, clipped to the image
    const int64_t x_lo = std::min({x[0], x[1], x[2]}), x_hi = std::max({x[0], x[1], x[2]});
    const int64_t y_lo = std::min({y[0], y[1], y[2]}), y_hi = std::max({y[0], y[1], y[2]});
    const int64_t u0 = std::max<int64_t>(-Floor2(-x_lo, shift), 0);
    const int64_t u1 = std::min<int64_t>(Floor2(x_hi, shift), image.cols - 1);
    const int64_t v0 = std::max<int64_t>(-Floor2(-y_lo, shift), 0);
    const int64_t v1 = std::min<int64_t>(Floor2(y_hi, shift), image.rows - 1);
    for (int64_t v = v0; v <= v1; ++v) {
      const int64_t py = v * one;
      int32_t* row = image.data + v * image.cols;
      for (int64_t u = u0; u <= u1; ++u) {
        const int64_t px = u * one;
        bool inside = true;
        for (int e = 0; e < 3 && inside; ++e) {
          const int64_t value = a[e] * px + b[e] * py + k[e];
          inside = value > 0 || (value == 0 && tie[e]);
        }
        if (inside) row[u] = ids[t];
      }
    }
  }
}

void CheckPixelIndices(const int64_t* index, int64_t begin, int64_t end, int64_t size,
                       const char* field) {
  for (int64_t i = begin; i < end; ++i) {
    if (index[i] < 0 || index[i] >= size) {
      throw RasterError(field, "index " + std::to_string(index[i]) + " at " + std::to_string(i) +
                                   " is outside the image's " + std::to_string(size) + " pixels");
    }
  }
}

}  // namespace bimcap::raster
