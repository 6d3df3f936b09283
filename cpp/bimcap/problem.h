// The problem data: every input of one solve as named dense arrays (see docs/architecture.md,
// "Solver problem"). The arrays are *views*: the caller (numpy, a problem file in memory) keeps
// the memory alive; `owner` may hold it.
#ifndef BIMCAP_PROBLEM_H_
#define BIMCAP_PROBLEM_H_

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
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

// The arrays of one solve. The five arrays every problem has are members; the arrays of the
// residual terms are declared by the terms themselves (TermSpec::arrays in the registry,
// terms.cc) and held by name. Read them with F64() / I32(), which return an empty view for an
// absent array; write them with Set().
struct ProblemData {
  ArrayRef<double> poses;                                     // (N, 7) world_from_cam, TUM order
  ArrayRef<double> timestamps;                                // (N,)
  ArrayRef<int32_t> pose_fixed;                               // (N,) 1 = constant
  ArrayRef<double> cameras;                                   // (C, 4) fx fy cx cy
  ArrayRef<int32_t> frame_camera;                             // (N,)
  std::map<std::string, ArrayRef<double>, std::less<>> f64;   // the terms' float64 arrays
  std::map<std::string, ArrayRef<int32_t>, std::less<>> i32;  // the terms' int32 arrays

  // Keeps the memory behind the views alive (a file buffer); may be empty.
  std::shared_ptr<const void> owner;

  int64_t num_poses() const { return poses.rows; }
  // Any array by name, the five members included; empty when absent.
  ArrayRef<double> F64(std::string_view name) const;
  ArrayRef<int32_t> I32(std::string_view name) const;
  void Set(std::string_view name, ArrayRef<double> array);
  void Set(std::string_view name, ArrayRef<int32_t> array);
};

// One row of the field table: name, dtype, number of columns (0 for a 1-D array), whether the
// array must be present, and the term that declared it ("" for the five core arrays).
struct FieldSpec {
  const char* name;
  DType dtype;
  int cols;
  bool required;
  const char* term;
};

// All fields: the five core arrays, then each term's arrays in registry order (an array that
// several terms read, such as `planes` or `segments`, once).
const std::vector<FieldSpec>& ProblemFields();
const FieldSpec* FindField(std::string_view name);

// Label ids used by segment_class (bimcap.labels.Label).
inline constexpr int32_t kLabelWall = 1;
inline constexpr int32_t kLabelColumn = 4;

// Checks the core arrays (shapes, finiteness, unit quaternions within 1e-3 as the TUM reader,
// index ranges, positive focal lengths), then each term's arrays with the term's own check
// (TermSpec::validate). Throws ProblemError naming the field.
void ValidateProblem(const ProblemData& problem);

}  // namespace bimcap

#endif  // BIMCAP_PROBLEM_H_
