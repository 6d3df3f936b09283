// Per-pixel front-end stages in compiled code (bimcap/raster/): the linear depth completion's
// triangle-id image (cv2.fillConvexPoly's pixels) and piecewise affine depth over it
// (bimcap.fusion.completion), the planar smoothing's regions and move of depth onto planes
// (ibid.), the geometric segmenter's points and normals and its RANSAC score tables' counts
// (bimcap.segmentation.geometric), and semantic sampling's pixel surface area
// (bimcap.frontend.semantic_map).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <algorithm>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "bimcap/raster/component_pixels.h"
#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/delaunay.h"
#include "bimcap/raster/depth_normals.h"
#include "bimcap/raster/descriptor_split.h"
#include "bimcap/raster/gray.h"
#include "bimcap/raster/near_region.h"
#include "bimcap/raster/piecewise_affine.h"
#include "bimcap/raster/pixel_neighbours.h"
#include "bimcap/raster/plane_depth.h"
#include "bimcap/raster/plane_scores.h"
#include "bimcap/raster/png_rows.h"
#include "bimcap/raster/point_neighbours.h"
#include "bimcap/raster/range_noise.h"
#include "bimcap/raster/region_rays.h"
#include "bimcap/raster/region_sums.h"
#include "bimcap/raster/rootsift.h"
#include "bimcap/raster/similarity_top2.h"
#include "bimcap/raster/surface_area.h"
#include "bimcap/raster/triangle_filter.h"
#include "bimcap/raster/voxel_normals.h"
#include "bimcap/raster/window_min.h"
#include "python/arrays.h"

namespace bimcap::python {
namespace {

using raster::RasterError;

std::string ShapeText(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) {
    s += (i ? ", " : "") + std::to_string(a.shape(i));
  }
  return s + (a.ndim() == 1 ? ",)" : ")");
}

// `obj` as a C-contiguous numpy array of dtype T with `ndim` dimensions; `shape` entries >= 0
// are required sizes (-1: any). Never copies: a wrong dtype, shape or layout is an error.
template <typename T>
py::array Checked(const py::handle& obj, const char* name, std::vector<py::ssize_t> shape) {
  const char* dtype_name = std::is_same_v<T, bool>      ? "bool"
                           : std::is_same_v<T, double>  ? "float64"
                           : std::is_same_v<T, float>   ? "float32"
                           : std::is_same_v<T, int64_t> ? "int64"
                           : std::is_same_v<T, uint8_t> ? "uint8"
                                                        : "int32";
  if (!py::isinstance<py::array>(obj)) {
    throw RasterError(name, std::string("expected a numpy array of ") + dtype_name + ", got " +
                                py::cast<std::string>(py::str(py::type::of(obj))));
  }
  py::array a = py::reinterpret_borrow<py::array>(obj);
  if (!a.dtype().equal(py::dtype::of<T>())) {
    throw RasterError(name, std::string("expected dtype ") + dtype_name + ", got " +
                                py::cast<std::string>(py::str(a.dtype())));
  }
  bool ok = a.ndim() == static_cast<py::ssize_t>(shape.size());
  for (size_t i = 0; ok && i < shape.size(); ++i) ok = shape[i] < 0 || a.shape(i) == shape[i];
  if (!ok) {
    std::string want = "(";
    for (size_t i = 0; i < shape.size(); ++i) {
      want += (i ? ", " : "") + (shape[i] < 0 ? std::string("n") : std::to_string(shape[i]));
    }
    throw RasterError(name, "expected shape " + want + (shape.size() == 1 ? ",)" : ")") + ", got " +
                                ShapeText(a));
  }
  if (!(a.flags() & py::array::c_style)) {
    throw RasterError(name, "array must be C-contiguous (use numpy.ascontiguousarray)");
  }
  return a;
}

py::array_t<int32_t> FillTriangleIds(const py::handle& corners_obj, const py::handle& ids_obj,
                                     py::ssize_t height, py::ssize_t width, int shift,
                                     bool centres) {
  for (const auto& [name, side] : {std::pair{"height", height}, std::pair{"width", width}}) {
    if (side < 0 || side > raster::kMaxCoordinatePx) {
      throw RasterError(name, "must be in [0, " + std::to_string(raster::kMaxCoordinatePx) +
                                  "] px, got " + std::to_string(side));
    }
  }
  const py::array corners = Checked<int32_t>(corners_obj, "corners", {-1, 3, 2});
  const py::array ids = Checked<int32_t>(ids_obj, "ids", {corners.shape(0)});
  py::array_t<int32_t> image({height, width});
  raster::ImageRef<int32_t> view{image.mutable_data(), height, width};
  std::fill(view.data, view.data + height * width, 0);
  const auto* c = static_cast<const int32_t*>(corners.data());
  const auto* k = static_cast<const int32_t*>(ids.data());
  const int64_t count = corners.shape(0);
  {
    py::gil_scoped_release release;
    raster::FillTriangleIds(view, c, k, count, shift);
    if (centres) raster::FillContainingTriangleIds(view, c, k, count, shift);
  }
  return image;
}

py::array_t<int32_t> DelaunayTriangles(const py::handle& points_obj) {
  const py::array points = Checked<double>(points_obj, "points", {-1, 2});
  const auto* xy = static_cast<const double*>(points.data());
  const int64_t n = points.shape(0);
  std::vector<int32_t> triangles;
  {
    py::gil_scoped_release release;
    triangles = raster::DelaunayTriangles(xy, n);
  }
  const auto count = static_cast<py::ssize_t>(triangles.size() / 3);
  py::array_t<int32_t> out({count, py::ssize_t{3}});
  std::copy(triangles.begin(), triangles.end(), out.mutable_data());
  return out;
}

py::array_t<float> EvaluatePiecewiseAffine(const py::handle& ids_obj, const py::handle& coef_obj,
                                           bool inverse_depth) {
  const py::array ids = Checked<int32_t>(ids_obj, "tri_id", {-1, -1});
  const py::array coef = Checked<double>(coef_obj, "coef", {3, -1});
  const py::ssize_t rows = ids.shape(0), cols = ids.shape(1);
  py::array_t<float> out({rows, cols});
  const raster::ImageRef<const int32_t> in{static_cast<const int32_t*>(ids.data()), rows, cols};
  const raster::ImageRef<float> view{out.mutable_data(), rows, cols};
  const auto* table = static_cast<const double*>(coef.data());
  const int64_t count = coef.shape(1);
  {
    py::gil_scoped_release release;
    raster::EvaluatePiecewiseAffine(
        in, table, count,
        inverse_depth ? raster::AffineValue::kInverseDepth : raster::AffineValue::kDepth, view);
  }
  return out;
}

py::array_t<uint8_t> RgbToGray(const py::handle& image_obj) {
  const py::array image = Checked<uint8_t>(image_obj, "image", {-1, -1, 3});
  const py::ssize_t rows = image.shape(0), cols = image.shape(1);
  py::array_t<uint8_t> gray({rows, cols});
  const auto* rgb = static_cast<const uint8_t*>(image.data());
  uint8_t* out = gray.mutable_data();
  {
    py::gil_scoped_release release;
    raster::RgbToGray(rgb, static_cast<int64_t>(rows) * cols, out);
  }
  return gray;
}

py::array_t<uint8_t> DecodePngRows(const py::handle& stream_obj, int64_t rows, int64_t row_bytes,
                                   int bpp) {
  if (rows < 1 || row_bytes < 1) {
    throw RasterError("rows", "rows and row_bytes must be >= 1, got " + std::to_string(rows) +
                                  " and " + std::to_string(row_bytes));
  }
  const py::array stream = Checked<uint8_t>(stream_obj, "stream", {-1});
  py::array_t<uint8_t> out({static_cast<py::ssize_t>(rows), static_cast<py::ssize_t>(row_bytes)});
  const auto* in = static_cast<const uint8_t*>(stream.data());
  const int64_t in_bytes = stream.shape(0);
  uint8_t* dst = out.mutable_data();
  {
    py::gil_scoped_release release;
    raster::DecodePngRows(in, in_bytes, rows, row_bytes, bpp, dst);
  }
  return out;
}

py::array_t<int64_t> NearestPixels(const py::handle& row_start_obj, const py::handle& cols_obj,
                                   const py::handle& queries_obj, int k) {
  const py::array row_start = Checked<int64_t>(row_start_obj, "row_start", {-1});
  if (row_start.shape(0) < 2) {
    throw RasterError("row_start", "needs at least 2 offsets (one row), got " +
                                       std::to_string(row_start.shape(0)));
  }
  const py::array cols = Checked<int64_t>(cols_obj, "cols", {-1});
  const py::array queries = Checked<double>(queries_obj, "queries", {-1, 2});
  const py::ssize_t num_queries = queries.shape(0);
  if (k < 1) throw RasterError("k", "must be >= 1, got " + std::to_string(k));
  py::array_t<int64_t> nearest({num_queries, static_cast<py::ssize_t>(k)});
  const auto* starts = static_cast<const int64_t*>(row_start.data());
  const auto* c = static_cast<const int64_t*>(cols.data());
  const auto* q = static_cast<const double*>(queries.data());
  int64_t* out = nearest.mutable_data();
  {
    py::gil_scoped_release release;
    raster::NearestPixels(starts, row_start.shape(0) - 1, c, cols.shape(0), q, num_queries, k, out);
  }
  return nearest;
}

py::array_t<int64_t> NearRegion(const py::handle& region_id_obj, int32_t k, int reach,
                                const py::handle& at_obj, bool rows_ascending, int64_t top,
                                int64_t stop) {
  const py::array region_id = Checked<int32_t>(region_id_obj, "region_id", {-1, -1});
  const py::array at = Checked<int64_t>(at_obj, "at", {-1});
  const raster::ImageRef<const int32_t> image{static_cast<const int32_t*>(region_id.data()),
                                              region_id.shape(0), region_id.shape(1)};
  const auto* entries = static_cast<const int64_t*>(at.data());
  std::vector<int64_t> hits;
  {
    py::gil_scoped_release release;
    hits = raster::NearRegion(image, k, reach, entries, at.shape(0), rows_ascending, top, stop);
  }
  py::array_t<int64_t> out(static_cast<py::ssize_t>(hits.size()));
  std::copy(hits.begin(), hits.end(), out.mutable_data());
  return out;
}

py::tuple SplitDescriptors(const py::handle& d_obj) {
  const py::array d = Checked<uint8_t>(d_obj, "descriptors", {-1, -1});
  const py::ssize_t rows = d.shape(0), cols = d.shape(1);
  const auto* src = static_cast<const uint8_t*>(d.data());
  py::array_t<int64_t> order(rows);
  const int64_t first = raster::HighBitLastOrder(src, rows, cols, order.mutable_data());
  const py::ssize_t num_hi = rows - static_cast<py::ssize_t>(first);
  py::array_t<uint8_t> ordered({rows, cols}), lo({rows, cols}), hi({num_hi, cols});
  py::array_t<int8_t> lo_t({cols, rows}), hi_t({cols, num_hi});
  raster::SplitDescriptors(src, rows, cols, order.data(), first, ordered.mutable_data(),
                           lo.mutable_data(), lo_t.mutable_data(), hi.mutable_data(),
                           hi_t.mutable_data());
  return py::make_tuple(order, first, ordered, lo, lo_t, hi, hi_t);
}

py::array_t<int64_t> NearestPoints(const py::handle& points_obj, const py::handle& queries_obj,
                                   int k, double cell) {
  const py::array points = Checked<double>(points_obj, "points", {-1, 3});
  const py::array queries = Checked<double>(queries_obj, "queries", {-1, 3});
  if (k < 1) throw RasterError("k", "must be >= 1, got " + std::to_string(k));
  const py::ssize_t num_queries = queries.shape(0);
  py::array_t<int64_t> nearest({num_queries, static_cast<py::ssize_t>(k)});
  const auto* p = static_cast<const double*>(points.data());
  const auto* q = static_cast<const double*>(queries.data());
  int64_t* out = nearest.mutable_data();
  {
    py::gil_scoped_release release;
    raster::NearestPoints(p, points.shape(0), q, num_queries, k, cell, out);
  }
  return nearest;
}

py::array_t<float> WindowMinAt(const py::handle& depth_obj, const py::handle& at_obj, int radius) {
  const py::array depth = Checked<float>(depth_obj, "depth", {-1, -1});
  const py::array at = Checked<int64_t>(at_obj, "at", {-1});
  const raster::ImageRef<const float> image{static_cast<const float*>(depth.data()), depth.shape(0),
                                            depth.shape(1)};
  py::array_t<float> zmin(at.shape(0));
  const auto* entries = static_cast<const int64_t*>(at.data());
  float* out = zmin.mutable_data();
  {
    py::gil_scoped_release release;
    raster::WindowMinAt(image, entries, at.shape(0), radius, out);
  }
  return zmin;
}

py::array_t<uint8_t> RootSiftU8(const py::handle& desc_obj) {
  const py::array desc = Checked<float>(desc_obj, "descriptors", {-1, -1});
  const py::ssize_t rows = desc.shape(0), cols = desc.shape(1);
  py::array_t<uint8_t> out({rows, cols});
  const auto* in = static_cast<const float*>(desc.data());
  uint8_t* dst = out.mutable_data();
  {
    py::gil_scoped_release release;
    raster::RootSiftU8(in, rows, cols, dst);
  }
  return out;
}

py::tuple RegionRays(const py::handle& flat_obj, int64_t width, double fx, double fy, double cx,
                     double cy, const py::handle& depth_obj, const py::handle& measured_obj) {
  const py::array flat = Checked<int64_t>(flat_obj, "flat", {-1});
  const py::array depth = Checked<float>(depth_obj, "depth", {-1});
  std::optional<py::array> measured;
  if (!measured_obj.is_none()) {
    measured = Checked<float>(measured_obj, "measured", {depth.shape(0)});
  }
  if (width < 1) throw RasterError("width", "must be >= 1, got " + std::to_string(width));
  const auto* f = static_cast<const int64_t*>(flat.data());
  const auto* d = static_cast<const float*>(depth.data());
  const float* m = measured ? static_cast<const float*>(measured->data()) : nullptr;
  raster::RegionRays rays;
  {
    py::gil_scoped_release release;
    rays =
        raster::GatherRegionRays(f, flat.shape(0), width, depth.shape(0), {fx, fy, cx, cy}, d, m);
  }
  const auto to_array = [](const std::vector<double>& v) {
    py::array_t<double> a(static_cast<py::ssize_t>(v.size()));
    std::copy(v.begin(), v.end(), a.mutable_data());
    return a;
  };
  py::array_t<double> returns({static_cast<py::ssize_t>(rays.returns.size() / 3), py::ssize_t{3}});
  std::copy(rays.returns.begin(), rays.returns.end(), returns.mutable_data());
  return py::make_tuple(to_array(rays.x), to_array(rays.y), to_array(rays.cur), returns);
}

py::array_t<double> PixelSurfaceArea(const py::handle& depth_obj, double fx, double fy, double cx,
                                     double cy, double min_cos) {
  const py::array depth = Checked<double>(depth_obj, "depth", {-1, -1});
  const py::ssize_t rows = depth.shape(0), cols = depth.shape(1);
  py::array_t<double> area({rows, cols});
  const raster::ImageRef<const double> in{static_cast<const double*>(depth.data()), rows, cols};
  const raster::ImageRef<double> out{area.mutable_data(), rows, cols};
  {
    py::gil_scoped_release release;
    raster::PixelSurfaceArea(in, {fx, fy, cx, cy}, min_cos, out);
  }
  return area;
}

py::tuple FilterTriangles(const py::handle& uv_obj, const py::handle& z_obj,
                          const py::handle& triangles_obj, double max_edge, double max_ratio) {
  const py::array uv = Checked<double>(uv_obj, "uv", {-1, 2});
  const py::ssize_t n = uv.shape(0);
  const py::array z = Checked<double>(z_obj, "z", {n});
  const py::array triangles = Checked<int32_t>(triangles_obj, "triangles", {-1, 3});
  const auto* p = static_cast<const double*>(uv.data());
  const auto* d = static_cast<const double*>(z.data());
  const auto* t = static_cast<const int32_t*>(triangles.data());
  const py::ssize_t count = triangles.shape(0);
  raster::TriangleFilter filter;
  {
    py::gil_scoped_release release;
    filter = raster::FilterTriangles(p, d, n, t, count, max_edge, max_ratio);
  }
  const auto num_good = static_cast<py::ssize_t>(filter.good.size());
  py::array_t<int64_t> good(num_good);
  std::copy(filter.good.begin(), filter.good.end(), good.mutable_data());
  py::array_t<int32_t> corners({num_good, py::ssize_t{3}, py::ssize_t{2}});
  raster::TriangleCorners(p, t, filter.good, corners.mutable_data());
  py::array_t<double> edge(count), det(count);
  std::copy(filter.edge.begin(), filter.edge.end(), edge.mutable_data());
  std::copy(filter.det.begin(), filter.det.end(), det.mutable_data());
  return py::make_tuple(good, corners, edge, det);
}

py::tuple RegionPlaneSums(const py::handle& comp_obj, const py::handle& valid_obj,
                          const py::handle& depth_obj, double fx, double fy, double cx, double cy,
                          int64_t num_regions) {
  const py::array comp = Checked<int32_t>(comp_obj, "comp", {-1, -1});
  const py::ssize_t rows = comp.shape(0), cols = comp.shape(1);
  const py::array valid = Checked<bool>(valid_obj, "valid", {rows, cols});
  const py::array depth = Checked<float>(depth_obj, "depth", {rows, cols});
  if (num_regions < 1) {
    throw RasterError("num_regions", "must be >= 1, got " + std::to_string(num_regions));
  }
  py::array_t<int64_t> count(num_regions);
  py::array_t<double> ata({static_cast<py::ssize_t>(num_regions), py::ssize_t{3}, py::ssize_t{3}});
  py::array_t<double> atb({static_cast<py::ssize_t>(num_regions), py::ssize_t{3}});
  const raster::ImageRef<const int32_t> c{static_cast<const int32_t*>(comp.data()), rows, cols};
  const raster::ImageRef<const bool> v{static_cast<const bool*>(valid.data()), rows, cols};
  const raster::ImageRef<const float> z{static_cast<const float*>(depth.data()), rows, cols};
  int64_t* n = count.mutable_data();
  double* a = ata.mutable_data();
  double* b = atb.mutable_data();
  {
    py::gil_scoped_release release;
    raster::RegionPlaneSums(c, v, z, {fx, fy, cx, cy}, num_regions, n, a, b);
  }
  return py::make_tuple(count, ata, atb);
}

py::object ScanRangeNoise(const py::handle& points_obj, double ring_bin_deg, double max_step_deg) {
  const py::array points = Checked<double>(points_obj, "points", {-1, 3});
  const auto* xyz = static_cast<const double*>(points.data());
  const int64_t count = points.shape(0);
  std::optional<double> sigma;
  {
    py::gil_scoped_release release;
    sigma = raster::ScanRangeNoise(xyz, count, ring_bin_deg, max_step_deg);
  }
  if (!sigma) return py::none();
  return py::float_(*sigma);
}

py::tuple VoxelMeans(const py::handle& points_obj, double min_range, double max_range,
                     double voxel) {
  const py::array points = Checked<double>(points_obj, "points", {-1, 3});
  const auto* xyz = static_cast<const double*>(points.data());
  const int64_t count = points.shape(0);
  raster::ScanVoxels voxels;
  {
    py::gil_scoped_release release;
    voxels = raster::VoxelMeans(xyz, count, min_range, max_range, voxel);
  }
  py::array_t<double> means({static_cast<py::ssize_t>(voxels.means.size() / 3), py::ssize_t{3}});
  std::copy(voxels.means.begin(), voxels.means.end(), means.mutable_data());
  return py::make_tuple(means, voxels.num_kept);
}

py::tuple PcaNormals(const py::handle& cloud_obj, const py::handle& neighbours_obj,
                     double max_flatness, double min_spread) {
  const py::array cloud = Checked<double>(cloud_obj, "cloud", {-1, 3});
  const py::array neighbours = Checked<int64_t>(neighbours_obj, "neighbours", {-1, -1});
  const py::ssize_t m = neighbours.shape(0);
  py::array_t<double> normals({m, py::ssize_t{3}});
  py::array_t<bool> planar(m);
  const auto* c = static_cast<const double*>(cloud.data());
  const auto* nb = static_cast<const int64_t*>(neighbours.data());
  double* n = normals.mutable_data();
  bool* p = planar.mutable_data();
  {
    py::gil_scoped_release release;
    raster::PcaNormals(c, cloud.shape(0), nb, m, neighbours.shape(1), max_flatness, min_spread, n,
                       p);
  }
  return py::make_tuple(normals, planar);
}

py::ssize_t MoveOntoPlanes(const py::handle& out_obj, const py::handle& flat_obj,
                           const py::handle& x_obj, const py::handle& y_obj,
                           const py::handle& depth_obj, const py::handle& planes_obj,
                           const py::handle& products_obj, double assign_threshold_m,
                           double max_change_rel) {
  py::array out = Checked<float>(out_obj, "out", {-1});
  if (!out.writeable()) throw RasterError("out", "array is read-only");
  const py::array flat = Checked<int64_t>(flat_obj, "flat", {-1});
  const py::ssize_t n = flat.shape(0);
  const py::array x = Checked<double>(x_obj, "ray_x", {n});
  const py::array y = Checked<double>(y_obj, "ray_y", {n});
  const py::array depth = Checked<double>(depth_obj, "depth", {n});
  const py::array planes = Checked<double>(planes_obj, "planes", {-1, 4});
  const py::ssize_t k = planes.shape(0);
  if (k < 1) throw RasterError("planes", "needs at least one plane, got (0, 4)");
  const double* table = nullptr;
  py::array products;
  if (k > 1 && !products_obj.is_none()) {
    products = Checked<double>(products_obj, "products", {n, k});
    table = static_cast<const double*>(products.data());
  }
  const raster::RegionPixels region{
      static_cast<const double*>(x.data()), static_cast<const double*>(y.data()),
      static_cast<const double*>(depth.data()), static_cast<const int64_t*>(flat.data()), n};
  const auto* plane_table = static_cast<const double*>(planes.data());
  auto* image = static_cast<float*>(out.mutable_data());
  const int64_t size = out.shape(0);
  py::gil_scoped_release release;
  return raster::MoveOntoPlanes(region, plane_table, k, table, {assign_threshold_m, max_change_rel},
                                image, size);
}

template <typename Cross>
py::tuple PointsAndCrossOf(const py::array& depth, const raster::Pinhole& camera, int64_t step,
                           double jump_offset_m) {
  const py::ssize_t rows = depth.shape(0), cols = depth.shape(1);
  py::array_t<double> points({rows, cols, py::ssize_t{3}});
  py::array_t<bool> valid({rows, cols});
  py::array_t<bool> ok({rows, cols});
  py::array_t<Cross> cross({rows, cols, py::ssize_t{3}});
  const raster::ImageRef<const float> in{static_cast<const float*>(depth.data()), rows, cols};
  const raster::DepthCrossOut<Cross> out{points.mutable_data(), valid.mutable_data(),
                                         ok.mutable_data(), cross.mutable_data()};
  {
    py::gil_scoped_release release;
    raster::DepthCross(in, camera, step, out, jump_offset_m);
  }
  return py::make_tuple(points, valid, ok, cross);
}

py::tuple PointsAndCross(const py::handle& depth_obj, double fx, double fy, double cx, double cy,
                         int64_t step, bool float32, double jump_offset_m) {
  const py::array depth = Checked<float>(depth_obj, "depth", {-1, -1});
  if (step < 1) throw RasterError("step", "must be >= 1 px, got " + std::to_string(step));
  const raster::Pinhole camera{fx, fy, cx, cy};
  return float32 ? PointsAndCrossOf<float>(depth, camera, step, jump_offset_m)
                 : PointsAndCrossOf<double>(depth, camera, step, jump_offset_m);
}

void OrientNormals(const py::handle& normals_obj, const py::handle& points_obj,
                   const py::handle& ok_obj) {
  py::array normals = Checked<double>(normals_obj, "normals", {-1, -1, 3});
  const py::ssize_t rows = normals.shape(0), cols = normals.shape(1);
  const py::array points = Checked<double>(points_obj, "points", {rows, cols, 3});
  py::array ok = Checked<bool>(ok_obj, "ok", {rows, cols});
  for (const auto& [name, a] : {std::pair{"normals", &normals}, std::pair{"ok", &ok}}) {
    if (!a->writeable()) throw RasterError(name, "array is read-only");
  }
  auto* n = static_cast<double*>(normals.mutable_data());
  const auto* p = static_cast<const double*>(points.data());
  auto* mask = static_cast<bool*>(ok.mutable_data());
  py::gil_scoped_release release;
  raster::OrientNormals(rows * cols, p, n, mask);
}

py::tuple ComponentPixels(const py::handle& labels_obj, int64_t count) {
  const py::array labels = Checked<int32_t>(labels_obj, "labels", {-1, -1});
  if (count < 1) throw RasterError("count", "must be >= 1, got " + std::to_string(count));
  const auto* data = static_cast<const int32_t*>(labels.data());
  const int64_t size = labels.shape(0) * labels.shape(1);
  py::array_t<int64_t> starts(count + 1);
  int64_t* s = starts.mutable_data();
  int64_t total = 0;
  {
    py::gil_scoped_release release;
    total = raster::ComponentStarts(data, size, count, s);
  }
  py::array_t<int64_t> pixels(total);
  int64_t* p = pixels.mutable_data();
  {
    py::gil_scoped_release release;
    raster::ComponentPixels(data, size, count, s, p);
  }
  return py::make_tuple(pixels, starts);
}

void AddPlaneScores(const py::handle& score_obj, const py::handle& points_obj,
                    const py::handle& normals_obj, const py::handle& planes_obj,
                    const py::handle& offsets_obj, const py::handle& thresholds_obj, double cos_n) {
  py::array score = Checked<int64_t>(score_obj, "score", {-1});
  if (!score.writeable()) throw RasterError("score", "array is read-only");
  const py::ssize_t hypotheses = score.shape(0);
  const py::array points = Checked<double>(points_obj, "points", {-1, 3});
  const py::ssize_t rows = points.shape(0);
  py::array normals;
  const double* normals_data = nullptr;
  if (!normals_obj.is_none()) {
    normals = Checked<double>(normals_obj, "normals", {rows, 3});
    normals_data = static_cast<const double*>(normals.data());
  }
  const py::array planes = Checked<double>(planes_obj, "planes", {hypotheses, 3});
  const py::array offsets = Checked<double>(offsets_obj, "offsets", {hypotheses});
  const py::array thresholds = Checked<double>(thresholds_obj, "thresholds", {rows});
  const auto* p = static_cast<const double*>(points.data());
  const auto* h = static_cast<const double*>(planes.data());
  const auto* d = static_cast<const double*>(offsets.data());
  const auto* thr = static_cast<const double*>(thresholds.data());
  auto* out = static_cast<int64_t*>(score.mutable_data());
  py::gil_scoped_release release;
  raster::AddPlaneScores(p, normals_data, h, d, thr, rows, hypotheses, cos_n, out);
}

py::tuple SimilarityTop2(const py::handle& sim_obj) {
  const py::array sim = Checked<int32_t>(sim_obj, "sim", {-1, -1});
  const py::ssize_t rows = sim.shape(0), cols = sim.shape(1);
  if (rows < 1 || cols < 2) {
    throw RasterError("sim", "expected at least 1 row and 2 columns, got " + ShapeText(sim));
  }
  py::array_t<int64_t> best(rows);
  py::array_t<int32_t> s1(rows), s2(rows), c1(cols), c2(cols);
  const auto* data = static_cast<const int32_t*>(sim.data());
  int64_t* best_p = best.mutable_data();
  int32_t *s1_p = s1.mutable_data(), *s2_p = s2.mutable_data();
  int32_t *c1_p = c1.mutable_data(), *c2_p = c2.mutable_data();
  {
    py::gil_scoped_release release;
    raster::SimilarityTop2(data, rows, cols, best_p, s1_p, s2_p, c1_p, c2_p);
  }
  return py::make_tuple(best, s1, s2, c1, c2);
}

}  // namespace

void BindRaster(py::module_& m) {
  m.def("fill_triangle_ids", &FillTriangleIds, py::arg("corners"), py::arg("ids"),
        py::arg("height"), py::arg("width"), py::arg("shift") = 4, py::arg("centres") = false,
        "(height, width) int32 image, 0 where no triangle is drawn, triangle t filled with "
        "ids[t] in order (a later one overwrites shared pixels): the pixels of "
        "cv2.fillConvexPoly(image, corners[t], ids[t], cv2.LINE_8, shift) called for t = 0, 1, "
        "... on a zero image; with centres, then every pixel whose centre a triangle contains "
        "(top-left rule on its edges: one triangle of a triangulation) takes that triangle's id, "
        "whatever the order (bimcap/raster/convex_fill.h). corners: (T, 3, 2) int32 x, y in "
        "1/2**shift px (C-contiguous); ids: (T,) int32; shift in [1, 16]; sides and coordinates "
        "up to 16384 px. Raises InputError naming the bad argument (nothing is drawn then).");
  m.def("delaunay_triangles", &DelaunayTriangles, py::arg("points"),
        "(T, 3) int32 vertex indices of the Delaunay triangles of the (n, 2) float64 points "
        "(C-contiguous, finite), each counter-clockwise in x right, y up, in the order a sweep "
        "of the convex hull made them (bimcap/raster/delaunay.h); repeated points are used "
        "once. Raises InputError for fewer than 3 distinct points or points on one line.");
  m.def("evaluate_piecewise_affine", &EvaluatePiecewiseAffine, py::arg("tri_id"), py::arg("coef"),
        py::arg("inverse_depth"),
        "(H, W) float32 depth from the (H, W) int32 triangle-id image and the (3, N) float64 "
        "table of affine functions f = ((c0 u) + (c1 v)) + c2 (column 0: no triangle): "
        "1 / max(f, 1e-12) where f > 0 else 0 (inverse_depth), or max(f, 0); numpy's "
        "arithmetic bit for bit. Raises InputError for an id outside [0, N) or a wrong "
        "dtype / shape / layout.");
  m.def("component_pixels", &ComponentPixels, py::arg("labels"), py::arg("count"),
        "(pixels (M,) int64, starts (count + 1,) int64): the raveled indices of the nonzero "
        "pixels of the (H, W) int32 label image `labels` (labels in [0, count), C-contiguous), "
        "grouped by label and row-major inside each; label c's are pixels[starts[c]:starts[c + "
        "1]] (what numpy's stable argsort and searchsorted give). Raises InputError for a label "
        "outside [0, count).");
  m.def("move_onto_planes", &MoveOntoPlanes, py::arg("out"), py::arg("flat"), py::arg("ray_x"),
        py::arg("ray_y"), py::arg("depth"), py::arg("planes"), py::arg("products"),
        py::arg("assign_threshold_m"), py::arg("max_change_rel"),
        "Moves one region's pixels of the raveled float32 depth map `out` onto the nearest of "
        "its planes along their rays, in place (bimcap.fusion.completion._smooth_region's "
        "arithmetic bit for bit); returns how many moved. flat: (n,) int64 indices into out; "
        "ray_x, ray_y: (n,) float64 rays (x, y, 1); depth: (n,) float64 current depths (m); "
        "planes: (K, 4) float64 n0 n1 n2 d; products: (n, K) float64 p · n_k, or None to form "
        "them here as numpy's matrix product of p = (x z, y z, z) forms them (fused "
        "multiply-adds; ignored when K = 1). Raises InputError naming the bad argument (nothing "
        "is written then).");
  m.def("points_and_cross", &PointsAndCross, py::arg("depth"), py::arg("fx"), py::arg("fy"),
        py::arg("cx"), py::arg("cy"), py::arg("step"), py::arg("float32"),
        py::arg("jump_offset_m") = 0.05,
        "(points (H, W, 3) float64, valid (H, W) bool, ok (H, W) bool, cross (H, W, 3)) of the "
        "(H, W) float32 z-depth map (m, 0 = none): the back-projected pixels, where there is "
        "depth, where the central differences at +-step px exist without a depth jump (|dz| "
        "< 2 (0.05 z + jump_offset_m)), and "
        "their cross product there (0 elsewhere; float32 when `float32`, for a blur, else "
        "float64); bimcap.segmentation.geometric._points_and_normals's arithmetic bit for bit.");
  m.def("orient_normals", &OrientNormals, py::arg("normals"), py::arg("points"), py::arg("ok"),
        "Normalises the (H, W, 3) float64 cross products `normals` in place, turns them toward "
        "the camera (against `points` (H, W, 3) float64), clears `ok` (H, W) bool where the "
        "norm is <= 1e-12 and sets the normals to 0 where `ok` is false; numpy's arithmetic "
        "bit for bit.");
  m.def("add_plane_scores", &AddPlaneScores, py::arg("score"), py::arg("points"),
        py::arg("normals"), py::arg("planes"), py::arg("offsets"), py::arg("thresholds"),
        py::arg("cos_n"),
        "Adds to score (I,) int64, in place, the number of points i where |p_i · h_j + d_j| < "
        "thresholds[i] and (normals not None) |n_i · h_j| > cos_n: the RANSAC score tables of "
        "bimcap.segmentation.geometric._plane_scores and bimcap.fusion.completion."
        "_inlier_counts, each 3-term product rounded as numpy's matrix product (OpenBLAS, FMA "
        "CPUs) forms it, without the tables (bimcap/raster/plane_scores.h). points, normals: "
        "(N, 3) float64; planes: (I, 3) float64 h_j; offsets: (I,) float64 d_j; thresholds: "
        "(N,) float64; all C-contiguous. Raises InputError naming the bad argument (nothing is "
        "written then).");
  m.def("similarity_top2", &SimilarityTop2, py::arg("sim"),
        "sim (rows, cols) int32, C-contiguous, rows >= 1, cols >= 2 -> (row_best int64, row_s1, "
        "row_s2, col_s1, col_s2 int32): per row the first column of its largest value, the "
        "largest and the second largest (with multiplicity), per column the largest and the "
        "second largest (INT32_MIN with one row); the descriptor matcher's reductions "
        "(bimcap.features.matching._match_numpy) in one pass.");
  m.def("rgb_to_gray", &RgbToGray, py::arg("image"),
        "(H, W) uint8 grey levels rint(0.299 r + 0.587 g + 0.114 b) of the (H, W, 3) uint8 RGB "
        "image (C-contiguous): bimcap.features.sift.to_gray_u8's numpy arithmetic bit for bit, "
        "in one pass.");
  m.def("decode_png_rows", &DecodePngRows, py::arg("stream"), py::arg("rows"), py::arg("row_bytes"),
        py::arg("bpp"),
        "(rows, row_bytes) uint8 scanlines of a PNG image from the zlib stream of its IDAT "
        "chunks ((n,) uint8, their data joined), `bpp` bytes a pixel (1-8): inflated by "
        "libdeflate and the PNG filters undone (bimcap/raster/png_rows.h). Raises InputError "
        "naming the bad argument (a stream that is not one zlib stream of exactly rows · (1 + "
        "row_bytes) bytes; a filter type above 4, with its row).");
  m.def("nearest_pixels", &NearestPixels, py::arg("row_start"), py::arg("cols"), py::arg("queries"),
        py::arg("k"),
        "(N, k) int64: for each of the (N, 2) float64 `queries` (x, y), the k nearest of the "
        "distinct pixels given row by row (`row_start` (rows + 1,) int64 offsets, `cols` (n,) "
        "int64 ascending in each row, as np.nonzero lists them), nearest first, ties by index: "
        "scipy cKDTree.query's neighbours and distances' rounding "
        "(bimcap/raster/pixel_neighbours.h). Raises InputError naming the bad argument.");
  m.def("near_region", &NearRegion, py::arg("region_id"), py::arg("k"), py::arg("reach"),
        py::arg("at"), py::arg("rows_ascending"), py::arg("top"), py::arg("stop"),
        "(n,) int64 positions (ascending) in `at` ((M,) int64 raveled pixels of the (h, w) int32 "
        "`region_id`; their rows never decrease when `rows_ascending`) of the pixels within "
        "`reach` rows and columns of a pixel of region `k`, whose pixels lie in rows [top, "
        "stop): what cv2.dilate(region_id == k, a (2 reach + 1)² square) covers there "
        "(bimcap/raster/near_region.h). Raises InputError naming the bad argument.");
  m.def("split_descriptors", &SplitDescriptors, py::arg("descriptors"),
        "(order (n,) int64, first, d[order], lo, lo_t int8, hi, hi_t int8) of the (n, c) uint8 "
        "descriptors: the rows without a value >= 128 first, then the others (first: how many "
        "without), d[order] & 127 and its transpose, d[order][first:] >> 7 and its transpose; "
        "bimcap.features.matching's numpy expressions byte for byte "
        "(bimcap/raster/descriptor_split.h).");
  m.def("nearest_points", &NearestPoints, py::arg("points"), py::arg("queries"), py::arg("k"),
        py::arg("cell"),
        "(N, k) int64: for each of the (N, 3) float64 `queries`, the k nearest of the (n, 3) "
        "float64 `points`, nearest first, ties by index: scipy cKDTree.query's neighbours and "
        "distances' rounding, found in a grid of cubes of side `cell` (only the cost depends "
        "on it; bimcap/raster/point_neighbours.h). Raises InputError naming the bad argument.");
  m.def("window_min_at", &WindowMinAt, py::arg("depth"), py::arg("at"), py::arg("radius"),
        "(K,) float32: at each of the (K,) int64 raveled pixels `at` of the (H, W) float32 "
        "`depth`, the least positive depth within `radius` rows and columns (FLT_MAX where "
        "none): cv2.erode(np.where(depth > 0, depth, FLT_MAX), a (2 radius + 1)² square) read "
        "there (bimcap/raster/window_min.h). Raises InputError naming the bad argument.");
  m.def("rootsift_u8", &RootSiftU8, py::arg("descriptors"),
        "(N, C) uint8 clip(rint(sqrt(d / max(Σ d, 1e-12)) · 512), 0, 255) of the (N, C) float32 "
        "descriptors, row by row, in numpy's float64 arithmetic bit for bit (its pairwise sum; "
        "bimcap/raster/rootsift.h).");
  m.def("region_rays", &RegionRays, py::arg("flat"), py::arg("width"), py::arg("fx"), py::arg("fy"),
        py::arg("cx"), py::arg("cy"), py::arg("depth"), py::arg("measured"),
        "(x, y, cur, returns) of the (N,) int64 raveled pixels `flat` of an image `width` wide: "
        "their pinhole rays' x = (u − cx) / fx and y = (v − cy) / fy, the (H·W,) float32 "
        "`depth` there (float64), and (R, 3) (x z, y z, z) where the (H·W,) float32 `measured` "
        "(or None) has z > 0, in order; numpy's arithmetic bit for bit "
        "(bimcap/raster/region_rays.h). Raises InputError naming the bad argument.");
  m.def("filter_triangles", &FilterTriangles, py::arg("uv"), py::arg("z"), py::arg("triangles"),
        py::arg("max_edge"), py::arg("max_ratio"),
        "(good (G,) int64 ascending, corners (G, 3, 2) int32, edge (T,), det (T,)) of the (T, 3) "
        "int32 `triangles` over the (n, 2) float64 pixels `uv` with depths `z` (n,): the "
        "longest edge, twice the signed area, which ones the linear completion keeps (edge <= "
        "max_edge, z ratio <= max_ratio, |det| > 2) and their corners rint(16 uv); numpy's "
        "arithmetic bit for bit (bimcap/raster/triangle_filter.h). Raises InputError for a "
        "vertex index out of range.");
  m.def("region_plane_sums", &RegionPlaneSums, py::arg("comp"), py::arg("valid"), py::arg("depth"),
        py::arg("fx"), py::arg("fy"), py::arg("cx"), py::arg("cy"), py::arg("num_regions"),
        "(count (n,) int64, ata (n, 3, 3) float64, atb (n, 3) float64): per region of the (H, W) "
        "int32 label image `comp`, over its pixels where the (H, W) bool `valid` holds, the "
        "normal equations of 1 / z ≈ a x + b y + c (x, y the pinhole's normalised pixel, z the "
        "(H, W) float32 depth); np.bincount's sums bit for bit "
        "(bimcap/raster/region_sums.h). Raises InputError for a valid pixel's region outside "
        "[0, num_regions) or mismatched shapes.");
  m.def("scan_range_noise", &ScanRangeNoise, py::arg("points"), py::arg("ring_bin_deg"),
        py::arg("max_step_deg"),
        "The range noise σ (m) of the (M, 3) float64 scan points (C-contiguous, sensor frame) "
        "from the second differences of the ranges along each ring, or None when fewer than "
        "100 triples qualify: bimcap.segmentation.geometric.scan_range_noise's numpy arithmetic "
        "bit for bit (bimcap/raster/range_noise.h).");
  m.def("pca_normals", &PcaNormals, py::arg("cloud"), py::arg("neighbours"),
        py::arg("max_flatness"), py::arg("min_spread"),
        "(normals (m, 3) float64, planar (m,) bool): for each row of the (m, k) int64 indices "
        "`neighbours` into the (n, 3) float64 `cloud` (both C-contiguous), the unit eigenvector "
        "of the least eigenvalue of the neighbours' covariance (sign arbitrary) and whether "
        "λ0 <= max_flatness λ1 and λ1 >= min_spread λ2; numpy's algorithm (mean, einsum, eigh) "
        "to rounding (bimcap/raster/voxel_normals.h). Raises InputError for an index out of "
        "range or k = 0.");
  m.def("voxel_means", &VoxelMeans, py::arg("points"), py::arg("min_range"), py::arg("max_range"),
        py::arg("voxel"),
        "(means (n, 3) float64, num_kept): of the (M, 3) float64 scan points (C-contiguous, m) "
        "whose range is in [min_range, max_range] (finite coordinates only when max_range is "
        "infinite), one mean a voxel of edge `voxel` in ascending flat key order, and how many "
        "points were kept; numpy's arithmetic (floor(p / voxel), np.bincount's sums in input "
        "order) bit for bit (bimcap/raster/voxel_normals.h). Raises InputError naming the bad "
        "argument.");
  m.def("pixel_surface_area", &PixelSurfaceArea, py::arg("depth"), py::arg("fx"), py::arg("fy"),
        py::arg("cx"), py::arg("cy"), py::arg("min_cos"),
        "(H, W) float64 surface area in m² each pixel of the (H, W) float64 z-depth map (m, "
        "0 = none, H, W >= 2, C-contiguous) covers: z² cos α / (fx fy) / clip(cos θ, min_cos, "
        "1), numpy's arithmetic of bimcap.frontend.semantic_map.pixel_surface_area bit for bit.");
}

}  // namespace bimcap::python
