#include "bimcap/raster/delaunay.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <string>
#include <vector>

namespace bimcap::raster {
namespace {

constexpr double kEpsilon = std::numeric_limits<double>::epsilon() / 2;  // 2^-53
// Shewchuk's first error bounds (orient2d's ccwerrboundA, incircle's iccerrboundA).
constexpr double kOrientBound = (3.0 + 16.0 * kEpsilon) * kEpsilon;
constexpr double kInCircleBound = (10.0 + 96.0 * kEpsilon) * kEpsilon;

// > 0 when a, b, c turn counter-clockwise (x right, y up), < 0 clockwise, 0 on one line.
double Orient(const double* a, const double* b, const double* c) {
  const double left = (a[0] - c[0]) * (b[1] - c[1]);
  const double right = (a[1] - c[1]) * (b[0] - c[0]);
  const double det = left - right;
  if (std::fabs(det) >= kOrientBound * (std::fabs(left) + std::fabs(right))) return det;
  using L = long double;
  return static_cast<double>((L(a[0]) - L(c[0])) * (L(b[1]) - L(c[1])) -
                             (L(a[1]) - L(c[1])) * (L(b[0]) - L(c[0])));
}

// > 0 when d lies inside the circumcircle of the counter-clockwise triangle a, b, c.
double InCircle(const double* a, const double* b, const double* c, const double* d) {
  const double adx = a[0] - d[0], ady = a[1] - d[1];
  const double bdx = b[0] - d[0], bdy = b[1] - d[1];
  const double cdx = c[0] - d[0], cdy = c[1] - d[1];
  const double bc = bdx * cdy, cb = cdx * bdy, ca = cdx * ady, ac = adx * cdy;
  const double ab = adx * bdy, ba = bdx * ady;
  const double alift = adx * adx + ady * ady;
  const double blift = bdx * bdx + bdy * bdy;
  const double clift = cdx * cdx + cdy * cdy;
  const double det = alift * (bc - cb) + blift * (ca - ac) + clift * (ab - ba);
  const double permanent = (std::fabs(bc) + std::fabs(cb)) * alift +
                           (std::fabs(ca) + std::fabs(ac)) * blift +
                           (std::fabs(ab) + std::fabs(ba)) * clift;
  if (std::fabs(det) >= kInCircleBound * permanent) return det;
  using L = long double;
  const L ax = L(a[0]) - L(d[0]), ay = L(a[1]) - L(d[1]);
  const L bx = L(b[0]) - L(d[0]), by = L(b[1]) - L(d[1]);
  const L cx = L(c[0]) - L(d[0]), cy = L(c[1]) - L(d[1]);
  return static_cast<double>((ax * ax + ay * ay) * (bx * cy - cx * by) +
                             (bx * bx + by * by) * (cx * ay - ax * cy) +
                             (cx * cx + cy * cy) * (ax * by - bx * ay));
}

// Squared circumradius of a, b, c (infinite when they are on one line).
double CircumradiusSquared(const double* a, const double* b, const double* c) {
  const double dx = b[0] - a[0], dy = b[1] - a[1];
  const double ex = c[0] - a[0], ey = c[1] - a[1];
  const double bl = dx * dx + dy * dy, cl = ex * ex + ey * ey;
  const double den = dx * ey - dy * ex;
  if (den == 0.0) return std::numeric_limits<double>::infinity();
  const double x = (ey * bl - dy * cl) * 0.5 / den;
  const double y = (dx * cl - ex * bl) * 0.5 / den;
  const double r = x * x + y * y;
  return std::isfinite(r) ? r : std::numeric_limits<double>::infinity();
}

class Sweep {
 public:
  Sweep(const double* xy, int32_t n) : xy_(xy), n_(n) {}

  std::vector<int32_t> Run();

 private:
  const double* P(int32_t i) const { return xy_ + 2 * static_cast<std::ptrdiff_t>(i); }

  // Bucket of the pseudo-angle of (x, y) around the seed's circumcentre, in [0, hash size).
  int32_t HashKey(const double* p) const {
    const double dx = p[0] - cx_, dy = p[1] - cy_;
    const double s = std::fabs(dx) + std::fabs(dy);
    const double q = s > 0.0 ? dx / s : 0.0;
    const double angle = (dy > 0.0 ? 3.0 - q : 1.0 + q) / 4.0;  // [0, 1]
    const auto key = static_cast<int32_t>(std::floor(angle * static_cast<double>(hash_size_)));
    return std::clamp<int32_t>(key, 0, hash_size_ - 1);
  }

  void Link(int32_t a, int32_t b) {
    halfedges_[a] = b;
    if (b != -1) halfedges_[b] = a;
  }

  int32_t AddTriangle(int32_t i0, int32_t i1, int32_t i2, int32_t a, int32_t b, int32_t c) {
    const auto t = static_cast<int32_t>(triangles_.size());
    triangles_.insert(triangles_.end(), {i0, i1, i2});
    halfedges_.insert(halfedges_.end(), {-1, -1, -1});
    Link(t, a);
    Link(t + 1, b);
    Link(t + 2, c);
    return t;
  }

  int32_t Legalize(int32_t a);

  const double* xy_;
  int32_t n_;
  double cx_ = 0.0, cy_ = 0.0;
  int32_t hash_size_ = 1;
  int32_t hull_start_ = 0;
  std::vector<int32_t> triangles_, halfedges_;
  std::vector<int32_t> hull_next_, hull_prev_, hull_tri_, hull_hash_;
  std::vector<int32_t> stack_;
};

// Lawson's flips from halfedge a: while the vertex across an edge lies inside the circumcircle of
// the triangle on this side, flip the edge (and check the two edges the flip exposes). Returns
// the halfedge that ends up in a's position after the last flip (a hull edge of the new point).
int32_t Sweep::Legalize(int32_t a) {
  stack_.clear();
  int32_t ar = 0;
  while (true) {
    const int32_t b = halfedges_[a];
    const int32_t a0 = a - a % 3;
    ar = a0 + (a + 2) % 3;
    if (b == -1) {  // a hull edge: nothing across it
      if (stack_.empty()) break;
      a = stack_.back();
      stack_.pop_back();
      continue;
    }
    const int32_t b0 = b - b % 3;
    const int32_t al = a0 + (a + 1) % 3;
    const int32_t bl = b0 + (b + 2) % 3;
    const int32_t p0 = triangles_[ar], pr = triangles_[a], pl = triangles_[al];
    const int32_t p1 = triangles_[bl];
    if (InCircle(P(p0), P(pr), P(pl), P(p1)) > 0.0) {
      triangles_[a] = p1;
      triangles_[b] = p0;
      const int32_t hbl = halfedges_[bl];
      if (hbl == -1) {  // the flipped edge's far side was on the hull: a takes bl's place there
        int32_t e = hull_start_;
        do {
          if (hull_tri_[e] == bl) {
            hull_tri_[e] = a;
            break;
          }
          e = hull_prev_[e];
        } while (e != hull_start_);
      }
      Link(a, hbl);
      Link(b, halfedges_[ar]);
      Link(ar, bl);
      stack_.push_back(b0 + (b + 1) % 3);
    } else {
      if (stack_.empty()) break;
      a = stack_.back();
      stack_.pop_back();
    }
  }
  return ar;
}

std::vector<int32_t> Sweep::Run() {
  double min_x = std::numeric_limits<double>::infinity(), min_y = min_x;
  double max_x = -min_x, max_y = -min_x;
  for (int32_t i = 0; i < n_; ++i) {
    const double* p = P(i);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1])) {
      throw RasterError("points", "point " + std::to_string(i) + " is not finite");
    }
    min_x = std::min(min_x, p[0]);
    min_y = std::min(min_y, p[1]);
    max_x = std::max(max_x, p[0]);
    max_y = std::max(max_y, p[1]);
  }
  const double mid[2] = {(min_x + max_x) / 2, (min_y + max_y) / 2};
  auto dist2 = [](const double* a, const double* b) {
    const double dx = a[0] - b[0], dy = a[1] - b[1];
    return dx * dx + dy * dy;
  };
  int32_t i0 = 0, i1 = -1, i2 = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int32_t i = 0; i < n_; ++i) {
    const double d = dist2(mid, P(i));
    if (d < best) best = d, i0 = i;
  }
  best = std::numeric_limits<double>::infinity();
  for (int32_t i = 0; i < n_; ++i) {
    const double d = dist2(P(i0), P(i));
    if (i != i0 && d > 0.0 && d < best) best = d, i1 = i;
  }
  best = std::numeric_limits<double>::infinity();
  for (int32_t i = 0; i1 >= 0 && i < n_; ++i) {
    if (i == i0 || i == i1) continue;
    const double r = CircumradiusSquared(P(i0), P(i1), P(i));
    if (r < best) best = r, i2 = i;
  }
  if (i2 < 0) throw RasterError("points", "the points are all on one line (or equal)");
  if (Orient(P(i0), P(i1), P(i2)) < 0.0) std::swap(i1, i2);
  {  // the seed's circumcentre
    const double *a = P(i0), *b = P(i1), *c = P(i2);
    const double dx = b[0] - a[0], dy = b[1] - a[1], ex = c[0] - a[0], ey = c[1] - a[1];
    const double bl = dx * dx + dy * dy, cl = ex * ex + ey * ey;
    const double den = dx * ey - dy * ex;
    cx_ = a[0] + (ey * bl - dy * cl) * 0.5 / den;
    cy_ = a[1] + (dx * cl - ex * bl) * 0.5 / den;
  }
  std::vector<double> dist(static_cast<size_t>(n_));
  const double centre[2] = {cx_, cy_};
  for (int32_t i = 0; i < n_; ++i) dist[i] = dist2(P(i), centre);
  std::vector<int32_t> ids(static_cast<size_t>(n_));
  for (int32_t i = 0; i < n_; ++i) ids[i] = i;
  std::sort(ids.begin(), ids.end(), [&](int32_t a, int32_t b) {
    if (dist[a] != dist[b]) return dist[a] < dist[b];
    if (P(a)[0] != P(b)[0]) return P(a)[0] < P(b)[0];
    if (P(a)[1] != P(b)[1]) return P(a)[1] < P(b)[1];
    return a < b;
  });

  hash_size_ = std::max<int32_t>(1, static_cast<int32_t>(std::ceil(std::sqrt(double(n_)))));
  hull_hash_.assign(static_cast<size_t>(hash_size_), -1);
  hull_next_.assign(static_cast<size_t>(n_), 0);
  hull_prev_.assign(static_cast<size_t>(n_), 0);
  hull_tri_.assign(static_cast<size_t>(n_), 0);
  hull_start_ = i0;
  hull_next_[i0] = hull_prev_[i2] = i1;
  hull_next_[i1] = hull_prev_[i0] = i2;
  hull_next_[i2] = hull_prev_[i1] = i0;
  hull_tri_[i0] = 0;
  hull_tri_[i1] = 1;
  hull_tri_[i2] = 2;
  hull_hash_[HashKey(P(i0))] = i0;
  hull_hash_[HashKey(P(i1))] = i1;
  hull_hash_[HashKey(P(i2))] = i2;
  const size_t max_triangles = 2 * static_cast<size_t>(n_);
  triangles_.reserve(3 * max_triangles);
  halfedges_.reserve(3 * max_triangles);
  AddTriangle(i0, i1, i2, -1, -1, -1);

  auto same = [&](int32_t a, int32_t b) { return P(a)[0] == P(b)[0] && P(a)[1] == P(b)[1]; };
  for (int32_t k = 0; k < n_; ++k) {
    const int32_t i = ids[k];
    if (k > 0 && same(i, ids[k - 1])) continue;  // a repeated point
    if (same(i, i0) || same(i, i1) || same(i, i2)) continue;
    const double* p = P(i);
    // a vertex of the hull near the point's angle, then the first hull edge it sees
    int32_t start = 0;
    const int32_t key = HashKey(p);
    for (int32_t j = 0; j < hash_size_; ++j) {
      start = hull_hash_[(key + j) % hash_size_];
      if (start != -1 && start != hull_next_[start]) break;
    }
    start = hull_prev_[start];
    int32_t e = start;
    int32_t q = hull_next_[e];
    while (Orient(P(e), P(q), p) >= 0.0) {  // p on the inner side of (or on) edge e → q
      e = q;
      q = hull_next_[e];
      if (e == start) {
        e = -1;
        break;
      }
    }
    if (e == -1) continue;  // sees no edge: a near-duplicate point

    int32_t t = AddTriangle(e, i, hull_next_[e], -1, -1, hull_tri_[e]);
    hull_tri_[i] = Legalize(t + 2);
    hull_tri_[e] = t;
    int32_t next = hull_next_[e];
    q = hull_next_[next];
    while (Orient(P(next), P(q), p) < 0.0) {  // walk forward over the edges it sees
      t = AddTriangle(next, i, q, hull_tri_[i], -1, hull_tri_[next]);
      hull_tri_[i] = Legalize(t + 2);
      hull_next_[next] = next;  // removed from the hull
      next = q;
      q = hull_next_[next];
    }
    if (e == start) {  // and backward
      q = hull_prev_[e];
      while (Orient(P(q), P(e), p) < 0.0) {
        t = AddTriangle(q, i, e, -1, hull_tri_[e], hull_tri_[q]);
        Legalize(t + 2);
        hull_tri_[q] = t;
        hull_next_[e] = e;
        e = q;
        q = hull_prev_[e];
      }
    }
    hull_start_ = hull_prev_[i] = e;
    hull_next_[e] = hull_prev_[next] = i;
    hull_next_[i] = next;
    hull_hash_[HashKey(p)] = i;
    hull_hash_[HashKey(P(e))] = e;
  }
  return std::move(triangles_);
}

}  // namespace

std::vector<int32_t> DelaunayTriangles(const double* xy, int64_t n) {
  if (n < 3) throw RasterError("points", "need at least 3 points, got " + std::to_string(n));
  if (n > (int64_t{1} << 28)) {
    throw RasterError("points", "at most 2^28 points, got " + std::to_string(n));
  }
  return Sweep(xy, static_cast<int32_t>(n)).Run();
}

}  // namespace bimcap::raster
