// numpy ↔ ProblemData for the bindings: strict dtype / shape / contiguity checks, no silent copies.
#ifndef BIMCAP_PYTHON_ARRAYS_H_
#define BIMCAP_PYTHON_ARRAYS_H_

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <map>
#include <string>
#include <vector>

#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap::python {

namespace py = pybind11;

// Views of the arrays in `arrays` (a dict name → numpy array); `keep_alive` receives the array
// objects, which must outlive the returned ProblemData. Raises TypeError (not a numpy array,
// wrong dtype) or ValueError (unknown or missing name, wrong ndim / columns, not C-contiguous).
ProblemData ProblemFromDict(const py::dict& arrays, std::vector<py::array>* keep_alive);

// Copies of every array of `problem` as a dict name → numpy array.
py::dict ProblemToDict(const ProblemData& problem);

// Options from a dict key → str/int/float/bool (values are converted with str(); bools as 0/1).
SolverOptions OptionsFromDict(const py::dict& options);
py::dict OptionsToDict(const SolverOptions& options);

template <typename T>
py::array_t<T> CopyToNumpy(const T* data, std::vector<py::ssize_t> shape) {
  py::array_t<T> out(shape);
  py::ssize_t n = 1;
  for (py::ssize_t s : shape) n *= s;
  if (n > 0) std::copy(data, data + n, out.mutable_data());
  return out;
}

void BindCostFunctions(py::module_& m);
void BindProblemFile(py::module_& m);
void BindRaster(py::module_& m);
void BindSolver(py::module_& m);

}  // namespace bimcap::python

#endif  // BIMCAP_PYTHON_ARRAYS_H_
