// The problem data: every input of one solve as named dense arrays (see docs/architecture.md,
// "Solver problem"). The arrays are *views*: the caller (numpy, a problem file in memory) keeps
// the memory alive; `owner` may hold it.
#ifndef BIMCAP_PROBLEM_H_
#define BIMCAP_PROBLEM_H_

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace bimcap {

// Any error in user data: a bad array, a bad file, a bad option. `field()` names the culprit.
class InputError : public std::invalid_argument {
 public:
  InputError(std::string field, std::string message)
      : std::invalid_argument(field.empty() ? message : field + ": " + message),
        field_(std::move(field)),
        message_(std::move(message)) {}
  const std::string& field() const { return field_; }
  const std::string& message() const { return message_; }

 private:
  std::string field_;
  std::string message_;
};

// A problem array with a wrong shape, a NaN, an index out of range ...
class ProblemError : public InputError {
 public:
  using InputError::InputError;
};

// A read-only, row-major view of a dense (rows, cols) array; cols = 1 for a 1-D array.
template <typename T>
struct ArrayRef {
  const T* data = nullptr;
  int64_t rows = 0;
  int64_t cols = 1;

  bool empty() const { return rows == 0; }
  const T* row(int64_t i) const { return data + i * cols; }
  T operator()(int64_t i, int64_t j = 0) const { return data[i * cols + j]; }
};

enum class DType : uint32_t { kFloat64 = 1, kInt32 = 2 };

struct ProblemData {
  ArrayRef<double> poses;              // (N, 7) world_from_cam, TUM order
  ArrayRef<double> timestamps;         // (N,)
  ArrayRef<int32_t> pose_fixed;        // (N,) 1 = constant
  ArrayRef<double> cameras;            // (C, 4) fx fy cx cy
  ArrayRef<int32_t> frame_camera;      // (N,)
  ArrayRef<int32_t> match_frames;      // (M, 2)
  ArrayRef<double> match_uv;           // (M, 4) ua va ub vb
  ArrayRef<double> match_depth;        // (M, 2) za zb (<= 0: unknown)
  ArrayRef<int32_t> track_obs_frame;   // (K,)
  ArrayRef<int32_t> track_obs_point;   // (K,)
  ArrayRef<double> track_obs_uv;       // (K, 2)
  ArrayRef<double> track_obs_depth;    // (K,) (<= 0: none)
  ArrayRef<double> track_points;       // (P, 3) initial landmarks
  ArrayRef<int32_t> floor_frame;       // (F,)
  ArrayRef<double> floor_p_in_cam;     // (F, 3)
  ArrayRef<int32_t> floor_plane;       // (F,) index into planes
  ArrayRef<int32_t> ceiling_frame;     // (F',)
  ArrayRef<double> ceiling_p_in_cam;   // (F', 3)
  ArrayRef<int32_t> ceiling_plane;     // (F',)
  ArrayRef<double> planes;             // (Q, 4) nx ny nz d
  ArrayRef<int32_t> wall_frame;        // (W,)
  ArrayRef<double> wall_p_in_cam;      // (W, 3)
  ArrayRef<int32_t> column_frame;      // (W',)
  ArrayRef<double> column_p_in_cam;    // (W', 3)
  ArrayRef<double> segments;           // (S, 4) x1 y1 x2 y2
  ArrayRef<int32_t> segment_class;     // (S,) 1 wall / 4 column
  ArrayRef<double> segment_z;          // (S, 2) zmin zmax
  ArrayRef<double> segment_normal;     // (S, 2) free-side unit normal, (0, 0) = both; optional

  // Keeps the memory behind the views alive (a file buffer); may be empty.
  std::shared_ptr<const void> owner;

  int64_t num_poses() const { return poses.rows; }
};

// One row of the field table: name, dtype, number of columns (0 for a 1-D array), whether the
// array must be present, and the member it fills.
struct FieldSpec {
  const char* name;
  DType dtype;
  int cols;
  bool required;
  ArrayRef<double> ProblemData::*f64;
  ArrayRef<int32_t> ProblemData::*i32;
};

// All fields, in the order of the table in docs/architecture.md.
const std::vector<FieldSpec>& ProblemFields();
const FieldSpec* FindField(const std::string& name);

// Label ids used by segment_class (bimcap.labels.Label).
inline constexpr int32_t kLabelWall = 1;
inline constexpr int32_t kLabelColumn = 4;

// Checks shapes, finiteness, unit quaternions (|q| within 1e-6 of 1 after the caller's
// normalisation is NOT assumed: within 1e-3, as the TUM reader), index ranges, positive focal
// lengths, unit plane normals, z ranges. Throws ProblemError naming the field.
void ValidateProblem(const ProblemData& problem);

}  // namespace bimcap

#endif  // BIMCAP_PROBLEM_H_
