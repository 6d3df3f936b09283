#include "bimcap/problem.h"

#include <cmath>

#include "bimcap/checks.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

std::string Str(int64_t v) { return std::to_string(v); }

struct CoreField {
  FieldSpec spec;
  ArrayRef<double> ProblemData::*f64;
  ArrayRef<int32_t> ProblemData::*i32;
};

// The five arrays every problem has.
const CoreField kCoreFields[] = {
    {{"poses", DType::kFloat64, 7, true, ""}, &ProblemData::poses, nullptr},
    {{"timestamps", DType::kFloat64, 0, true, ""}, &ProblemData::timestamps, nullptr},
    {{"pose_fixed", DType::kInt32, 0, true, ""}, nullptr, &ProblemData::pose_fixed},
    {{"cameras", DType::kFloat64, 4, true, ""}, &ProblemData::cameras, nullptr},
    {{"frame_camera", DType::kInt32, 0, true, ""}, nullptr, &ProblemData::frame_camera},
};

const CoreField* FindCore(std::string_view name) {
  for (const CoreField& f : kCoreFields) {
    if (name == f.spec.name) return &f;
  }
  return nullptr;
}

}  // namespace

void CheckFinite(const ArrayRef<double>& a, const std::string& name) {
  for (int64_t i = 0; i < a.rows * a.cols; ++i) {
    if (!std::isfinite(a.data[i])) {
      throw ProblemError(name, "row " + Str(i / a.cols) + " is not finite");
    }
  }
}

void CheckIndex(const ArrayRef<int32_t>& a, const std::string& name, int64_t upper) {
  for (int64_t i = 0; i < a.rows * a.cols; ++i) {
    if (a.data[i] < 0 || a.data[i] >= upper) {
      throw ProblemError(name, "row " + Str(i / a.cols) + ": index " + Str(a.data[i]) +
                                   " out of range [0, " + Str(upper) + ")");
    }
  }
}

void CheckPointsInCamera(const ProblemData& p, const std::string& prefix) {
  const ArrayRef<int32_t> frame = p.I32(prefix + "_frame");
  const ArrayRef<double> p_in_cam = p.F64(prefix + "_p_in_cam");
  CheckShape(frame, prefix + "_frame", frame.rows, 1);
  CheckShape(p_in_cam, prefix + "_p_in_cam", frame.rows, 3);
  CheckIndex(frame, prefix + "_frame", p.num_poses());
  CheckFinite(p_in_cam, prefix + "_p_in_cam");
}

ArrayRef<double> ProblemData::F64(std::string_view name) const {
  if (const CoreField* core = FindCore(name); core != nullptr && core->f64)
    return this->*(core->f64);
  const auto it = f64.find(name);
  return it == f64.end() ? ArrayRef<double>{} : it->second;
}

ArrayRef<int32_t> ProblemData::I32(std::string_view name) const {
  if (const CoreField* core = FindCore(name); core != nullptr && core->i32)
    return this->*(core->i32);
  const auto it = i32.find(name);
  return it == i32.end() ? ArrayRef<int32_t>{} : it->second;
}

void ProblemData::Set(std::string_view name, ArrayRef<double> array) {
  if (const CoreField* core = FindCore(name); core != nullptr && core->f64) {
    this->*(core->f64) = array;
  } else {
    f64[std::string(name)] = array;
  }
}

void ProblemData::Set(std::string_view name, ArrayRef<int32_t> array) {
  if (const CoreField* core = FindCore(name); core != nullptr && core->i32) {
    this->*(core->i32) = array;
  } else {
    i32[std::string(name)] = array;
  }
}

const std::vector<FieldSpec>& ProblemFields() {
  static const std::vector<FieldSpec> fields = [] {
    std::vector<FieldSpec> out;
    for (const CoreField& f : kCoreFields) out.push_back(f.spec);
    for (const TermSpec& term : Terms()) {
      for (const ArraySpec& a : term.arrays) {
        bool seen = false;
        for (const FieldSpec& f : out) seen = seen || std::string_view(f.name) == a.name;
        if (!seen) out.push_back(FieldSpec{a.name, a.dtype, a.cols, false, term.key});
      }
    }
    return out;
  }();
  return fields;
}

const FieldSpec* FindField(std::string_view name) {
  for (const FieldSpec& f : ProblemFields()) {
    if (name == f.name) return &f;
  }
  return nullptr;
}

void ValidateProblem(const ProblemData& p) {
  // Names and declared column counts first, so that the checks below may index freely.
  for (const auto& [name, a] : p.f64) {
    const FieldSpec* f = FindField(name);
    if (f == nullptr || f->dtype != DType::kFloat64)
      throw ProblemError(name, "unknown float64 array");
  }
  for (const auto& [name, a] : p.i32) {
    const FieldSpec* f = FindField(name);
    if (f == nullptr || f->dtype != DType::kInt32) throw ProblemError(name, "unknown int32 array");
  }
  for (const FieldSpec& f : ProblemFields()) {
    const bool f64 = f.dtype == DType::kFloat64;
    const int64_t rows = f64 ? p.F64(f.name).rows : p.I32(f.name).rows;
    const int64_t cols = f64 ? p.F64(f.name).cols : p.I32(f.name).cols;
    const bool has_data = f64 ? p.F64(f.name).data != nullptr : p.I32(f.name).data != nullptr;
    if (rows < 0 || cols < 1) throw ProblemError(f.name, "negative or empty shape");
    if (rows > 0 && !has_data) throw ProblemError(f.name, "no data");
    if (rows > 0 && cols != (f.cols == 0 ? 1 : f.cols)) {
      throw ProblemError(
          f.name, "expected " + Str(f.cols == 0 ? 1 : f.cols) + " columns, got " + Str(cols));
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

  // Each term's arrays, with the term's own checks.
  for (const TermSpec& term : Terms()) term.validate(p);
}

}  // namespace bimcap
