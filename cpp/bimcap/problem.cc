#include "bimcap/problem.h"

#include <cmath>
#include <sstream>

namespace bimcap {
namespace {

#define BIMCAP_F64(name, cols, required) \
  FieldSpec{#name, DType::kFloat64, cols, required, &ProblemData::name, nullptr}
#define BIMCAP_I32(name, cols, required) \
  FieldSpec{#name, DType::kInt32, cols, required, nullptr, &ProblemData::name}

std::string Str(int64_t v) { return std::to_string(v); }

template <typename T>
void CheckShape(const ArrayRef<T>& a, const char* name, int64_t rows, int64_t cols) {
  if (a.rows != rows || a.cols != cols) {
    std::ostringstream msg;
    msg << "expected shape (" << rows;
    if (cols != 1) msg << ", " << cols;
    msg << "), got (" << a.rows;
    if (a.cols != 1) msg << ", " << a.cols;
    msg << ")";
    throw ProblemError(name, msg.str());
  }
  if (a.rows > 0 && a.data == nullptr) throw ProblemError(name, "no data");
}

void CheckFinite(const ArrayRef<double>& a, const char* name) {
  for (int64_t i = 0; i < a.rows * a.cols; ++i) {
    if (!std::isfinite(a.data[i])) {
      throw ProblemError(name, "row " + Str(i / a.cols) + " is not finite");
    }
  }
}

void CheckIndex(const ArrayRef<int32_t>& a, const char* name, int64_t upper) {
  for (int64_t i = 0; i < a.rows * a.cols; ++i) {
    if (a.data[i] < 0 || a.data[i] >= upper) {
      throw ProblemError(name, "row " + Str(i / a.cols) + ": index " + Str(a.data[i]) +
                                   " out of range [0, " + Str(upper) + ")");
    }
  }
}

// A (rows,) frame index array, a (rows, 3) point array and optionally a (rows,) plane index.
void CheckSemantic(const ArrayRef<int32_t>& frame, const ArrayRef<double>& p_in_cam,
                   const char* frame_name, const char* p_name, int64_t num_poses) {
  if (frame.cols != 1) throw ProblemError(frame_name, "must be 1-D");
  CheckShape(p_in_cam, p_name, frame.rows, 3);
  CheckIndex(frame, frame_name, num_poses);
  CheckFinite(p_in_cam, p_name);
}

}  // namespace

const std::vector<FieldSpec>& ProblemFields() {
  static const std::vector<FieldSpec> fields = {
      BIMCAP_F64(poses, 7, true),
      BIMCAP_F64(timestamps, 0, true),
      BIMCAP_I32(pose_fixed, 0, true),
      BIMCAP_F64(cameras, 4, true),
      BIMCAP_I32(frame_camera, 0, true),
      BIMCAP_I32(match_frames, 2, false),
      BIMCAP_F64(match_uv, 4, false),
      BIMCAP_F64(match_depth, 2, false),
      BIMCAP_I32(track_obs_frame, 0, false),
      BIMCAP_I32(track_obs_point, 0, false),
      BIMCAP_F64(track_obs_uv, 2, false),
      BIMCAP_F64(track_obs_depth, 0, false),
      BIMCAP_F64(track_points, 3, false),
      BIMCAP_I32(floor_frame, 0, false),
      BIMCAP_F64(floor_p_in_cam, 3, false),
      BIMCAP_I32(floor_plane, 0, false),
      BIMCAP_I32(ceiling_frame, 0, false),
      BIMCAP_F64(ceiling_p_in_cam, 3, false),
      BIMCAP_I32(ceiling_plane, 0, false),
      BIMCAP_F64(planes, 4, false),
      BIMCAP_I32(wall_frame, 0, false),
      BIMCAP_F64(wall_p_in_cam, 3, false),
      BIMCAP_I32(column_frame, 0, false),
      BIMCAP_F64(column_p_in_cam, 3, false),
      BIMCAP_F64(segments, 4, false),
      BIMCAP_I32(segment_class, 0, false),
      BIMCAP_F64(segment_z, 2, false),
      BIMCAP_F64(segment_normal, 2, false),
  };
  return fields;
}

const FieldSpec* FindField(const std::string& name) {
  for (const FieldSpec& f : ProblemFields()) {
    if (name == f.name) return &f;
  }
  return nullptr;
}

void ValidateProblem(const ProblemData& p) {
  // Declared column counts first, so that the checks below may index freely.
  for (const FieldSpec& f : ProblemFields()) {
    const int64_t rows = f.f64 ? (p.*f.f64).rows : (p.*f.i32).rows;
    const int64_t cols = f.f64 ? (p.*f.f64).cols : (p.*f.i32).cols;
    const bool has_data = f.f64 ? (p.*f.f64).data != nullptr : (p.*f.i32).data != nullptr;
    if (rows < 0 || cols < 1) throw ProblemError(f.name, "negative or empty shape");
    if (rows > 0 && !has_data) throw ProblemError(f.name, "no data");
    if (rows > 0 && cols != (f.cols == 0 ? 1 : f.cols)) {
      throw ProblemError(f.name, "expected " + Str(f.cols == 0 ? 1 : f.cols) + " columns, got " +
                                     Str(cols));
    }
  }

  const int64_t n = p.poses.rows;
  if (n < 1) throw ProblemError("poses", "need at least one pose, got shape (0, 7)");
  CheckShape(p.poses, "poses", n, 7);
  CheckFinite(p.poses, "poses");
  for (int64_t i = 0; i < n; ++i) {
    const double* q = p.poses.row(i) + 3;
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (std::abs(norm - 1.0) > 1e-3) {
      throw ProblemError("poses", "pose " + Str(i) + " has a quaternion of norm " +
                                      std::to_string(norm) + ", expected 1");
    }
  }
  CheckShape(p.timestamps, "timestamps", n, 1);
  CheckFinite(p.timestamps, "timestamps");
  CheckShape(p.pose_fixed, "pose_fixed", n, 1);
  CheckIndex(p.pose_fixed, "pose_fixed", 2);

  const int64_t c = p.cameras.rows;
  if (c < 1) throw ProblemError("cameras", "need at least one camera");
  CheckShape(p.cameras, "cameras", c, 4);
  CheckFinite(p.cameras, "cameras");
  for (int64_t i = 0; i < c; ++i) {
    if (p.cameras(i, 0) <= 0 || p.cameras(i, 1) <= 0) {
      throw ProblemError("cameras", "camera " + Str(i) + " has a non-positive focal length");
    }
  }
  CheckShape(p.frame_camera, "frame_camera", n, 1);
  CheckIndex(p.frame_camera, "frame_camera", c);

  // G: matches.
  const int64_t m = p.match_frames.rows;
  CheckShape(p.match_frames, "match_frames", m, 2);
  CheckShape(p.match_uv, "match_uv", m, 4);
  CheckShape(p.match_depth, "match_depth", m, 2);
  CheckIndex(p.match_frames, "match_frames", n);
  CheckFinite(p.match_uv, "match_uv");
  CheckFinite(p.match_depth, "match_depth");
  for (int64_t i = 0; i < m; ++i) {
    if (p.match_frames(i, 0) == p.match_frames(i, 1)) {
      throw ProblemError("match_frames", "row " + Str(i) + " matches frame " +
                                             Str(p.match_frames(i, 0)) + " with itself");
    }
  }

  // G: tracks.
  const int64_t k = p.track_obs_frame.rows;
  const int64_t num_points = p.track_points.rows;
  CheckShape(p.track_obs_frame, "track_obs_frame", k, 1);
  CheckShape(p.track_obs_point, "track_obs_point", k, 1);
  CheckShape(p.track_obs_uv, "track_obs_uv", k, 2);
  CheckShape(p.track_obs_depth, "track_obs_depth", k, 1);
  CheckShape(p.track_points, "track_points", num_points, 3);
  CheckIndex(p.track_obs_frame, "track_obs_frame", n);
  CheckIndex(p.track_obs_point, "track_obs_point", num_points);
  CheckFinite(p.track_obs_uv, "track_obs_uv");
  CheckFinite(p.track_obs_depth, "track_obs_depth");
  CheckFinite(p.track_points, "track_points");

  // F / Ce.
  const int64_t q = p.planes.rows;
  CheckShape(p.planes, "planes", q, 4);
  CheckFinite(p.planes, "planes");
  for (int64_t i = 0; i < q; ++i) {
    const double* pl = p.planes.row(i);
    const double norm = std::sqrt(pl[0] * pl[0] + pl[1] * pl[1] + pl[2] * pl[2]);
    if (std::abs(norm - 1.0) > 1e-6) {
      throw ProblemError("planes", "plane " + Str(i) + " has a normal of norm " +
                                       std::to_string(norm) + ", expected 1");
    }
  }
  CheckSemantic(p.floor_frame, p.floor_p_in_cam, "floor_frame", "floor_p_in_cam", n);
  CheckShape(p.floor_plane, "floor_plane", p.floor_frame.rows, 1);
  CheckIndex(p.floor_plane, "floor_plane", q);
  CheckSemantic(p.ceiling_frame, p.ceiling_p_in_cam, "ceiling_frame", "ceiling_p_in_cam", n);
  CheckShape(p.ceiling_plane, "ceiling_plane", p.ceiling_frame.rows, 1);
  CheckIndex(p.ceiling_plane, "ceiling_plane", q);

  // W / Co.
  CheckSemantic(p.wall_frame, p.wall_p_in_cam, "wall_frame", "wall_p_in_cam", n);
  CheckSemantic(p.column_frame, p.column_p_in_cam, "column_frame", "column_p_in_cam", n);
  const int64_t s = p.segments.rows;
  CheckShape(p.segments, "segments", s, 4);
  CheckShape(p.segment_class, "segment_class", s, 1);
  CheckShape(p.segment_z, "segment_z", s, 2);
  CheckFinite(p.segments, "segments");
  CheckFinite(p.segment_z, "segment_z");
  for (int64_t i = 0; i < s; ++i) {
    const int32_t cls = p.segment_class(i);
    if (cls != kLabelWall && cls != kLabelColumn) {
      throw ProblemError("segment_class", "row " + Str(i) + ": class " + Str(cls) +
                                              " is neither 1 (wall) nor 4 (column)");
    }
    if (p.segment_z(i, 0) > p.segment_z(i, 1)) {
      throw ProblemError("segment_z", "row " + Str(i) + ": zmin > zmax");
    }
  }
  // Optional: absent (no visibility test) or one free-side normal per segment, unit or zero.
  if (!p.segment_normal.empty()) {
    CheckShape(p.segment_normal, "segment_normal", s, 2);
    CheckFinite(p.segment_normal, "segment_normal");
    for (int64_t i = 0; i < s; ++i) {
      const double norm = std::hypot(p.segment_normal(i, 0), p.segment_normal(i, 1));
      if (norm != 0.0 && std::abs(norm - 1.0) > 1e-6) {
        throw ProblemError("segment_normal", "row " + Str(i) + " has norm " +
                                                 std::to_string(norm) + ", expected 1 or 0");
      }
    }
  }
}

}  // namespace bimcap
