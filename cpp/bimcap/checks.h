// The checks ValidateProblem and each term's TermSpec::validate apply to problem arrays. Each
// throws ProblemError naming the array (and the row) on the first failure.
#ifndef BIMCAP_CHECKS_H_
#define BIMCAP_CHECKS_H_

#include <cstdint>
#include <string>

#include "bimcap/problem.h"

namespace bimcap {

// `a` has exactly (rows, cols) (cols = 1 for a 1-D array) and data behind a non-empty view. An
// absent array (no data, no rows) is an empty one of any width: a term's arrays may be left out.
template <typename T>
void CheckShape(const ArrayRef<T>& a, const std::string& name, int64_t rows, int64_t cols) {
  if (rows == 0 && a.rows == 0 && a.data == nullptr) return;
  if (a.rows != rows || a.cols != cols) {
    std::string msg = "expected shape (" + std::to_string(rows);
    if (cols != 1) msg += ", " + std::to_string(cols);
    msg += "), got (" + std::to_string(a.rows);
    if (a.cols != 1) msg += ", " + std::to_string(a.cols);
    throw ProblemError(name, msg + ")");
  }
  if (a.rows > 0 && a.data == nullptr) throw ProblemError(name, "no data");
}

// Every value finite.
void CheckFinite(const ArrayRef<double>& a, const std::string& name);

// Every value an index in [0, upper).
void CheckIndex(const ArrayRef<int32_t>& a, const std::string& name, int64_t upper);

// A (rows,) frame index array and its (rows, 3) points in the camera: `<prefix>_frame` and
// `<prefix>_p_in_cam`, the two arrays of every per-point semantic term.
void CheckPointsInCamera(const ProblemData& p, const std::string& prefix);

}  // namespace bimcap

#endif  // BIMCAP_CHECKS_H_
