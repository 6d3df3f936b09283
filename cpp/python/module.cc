// bimcap._core: the C++ Ceres core. The ergonomic API is bimcap.optimize (Python); this module
// takes and returns dense arrays only.
#include <pybind11/gil_safe_call_once.h>
#include <pybind11/pybind11.h>

#include "bimcap/problem.h"
#include "bimcap/problem_file.h"
#include "python/arrays.h"

namespace py = pybind11;

namespace bimcap::python {

// Dict → ProblemData conversion lives here, shared by the solver and problem-file bindings.
ProblemData ProblemFromDict(const py::dict& arrays, std::vector<py::array>* keep_alive) {
  ProblemData problem;
  for (const auto& item : arrays) {
    if (!py::isinstance<py::str>(item.first)) throw py::type_error("array names must be str");
    const std::string name = py::cast<std::string>(item.first);
    const FieldSpec* spec = FindField(name);
    if (spec == nullptr) throw py::value_error("unknown problem array '" + name + "'");
    if (!py::isinstance<py::array>(item.second)) {
      throw py::type_error(name + ": expected a numpy array, got " +
                           py::cast<std::string>(py::str(py::type::of(item.second))));
    }
    py::array array = py::reinterpret_borrow<py::array>(item.second);
    const bool f64 = spec->dtype == DType::kFloat64;
    const py::dtype want = f64 ? py::dtype::of<double>() : py::dtype::of<int32_t>();
    if (!array.dtype().is(want)) {
      throw py::type_error(name + ": expected dtype " + std::string(f64 ? "float64" : "int32") +
                           ", got " + py::cast<std::string>(py::str(array.dtype())));
    }
    const int want_ndim = spec->cols == 0 ? 1 : 2;
    if (array.ndim() != want_ndim) {
      throw py::value_error(name + ": expected a " + std::to_string(want_ndim) + "-D array, got " +
                            std::to_string(array.ndim()) + "-D");
    }
    if (want_ndim == 2 && array.shape(1) != spec->cols) {
      throw py::value_error(name + ": expected shape (n, " + std::to_string(spec->cols) +
                            "), got (" + std::to_string(array.shape(0)) + ", " +
                            std::to_string(array.shape(1)) + ")");
    }
    if (!(array.flags() & py::array::c_style)) {
      throw py::value_error(name + ": array must be C-contiguous (use numpy.ascontiguousarray)");
    }
    const int64_t rows = array.shape(0);
    const int64_t cols = want_ndim == 2 ? array.shape(1) : 1;
    if (f64) {
      problem.Set(name, ArrayRef<double>{static_cast<const double*>(array.data()), rows, cols});
    } else {
      problem.Set(name, ArrayRef<int32_t>{static_cast<const int32_t*>(array.data()), rows, cols});
    }
    keep_alive->push_back(array);
  }
  for (const FieldSpec& spec : ProblemFields()) {
    if (spec.required && !arrays.contains(spec.name)) {
      throw py::value_error(std::string(spec.name) + ": required array missing");
    }
  }
  return problem;
}

py::dict ProblemToDict(const ProblemData& problem) {
  py::dict out;
  for (const FieldSpec& spec : ProblemFields()) {
    if (spec.dtype == DType::kFloat64) {
      const ArrayRef<double> a = problem.F64(spec.name);
      std::vector<py::ssize_t> shape = {a.rows};
      if (spec.cols != 0) shape.push_back(spec.cols);
      out[spec.name] = CopyToNumpy<double>(a.data, shape);
    } else {
      const ArrayRef<int32_t> a = problem.I32(spec.name);
      std::vector<py::ssize_t> shape = {a.rows};
      if (spec.cols != 0) shape.push_back(spec.cols);
      out[spec.name] = CopyToNumpy<int32_t>(a.data, shape);
    }
  }
  return out;
}

SolverOptions OptionsFromDict(const py::dict& options) {
  std::map<std::string, std::string> values;
  for (const auto& item : options) {
    if (!py::isinstance<py::str>(item.first)) throw py::type_error("option names must be str");
    const std::string key = py::cast<std::string>(item.first);
    const py::handle v = item.second;
    if (py::isinstance<py::bool_>(v)) {
      values[key] = py::cast<bool>(v) ? "1" : "0";
    } else if (py::isinstance<py::float_>(v)) {
      values[key] = py::cast<std::string>(py::repr(v));
    } else {
      values[key] = py::cast<std::string>(py::str(v));
    }
  }
  return OptionsFromKeyValues(values);
}

py::dict OptionsToDict(const SolverOptions& options) {
  py::dict out;
  for (const auto& [k, v] : OptionsToKeyValues(options)) out[py::str(k)] = py::str(v);
  return out;
}

}  // namespace bimcap::python

PYBIND11_MODULE(_core, m) {
  m.doc() =
      "bimcap's C++ Ceres core. Use bimcap.optimize (solve, Problem, SolverOptions) rather than "
      "this module directly: it takes dense float64/int32 C-contiguous arrays by name.";
  // Every input error of the core is a ValueError (bimcap.optimize wraps it in SolverInputError).
  PYBIND11_CONSTINIT static py::gil_safe_call_once_and_store<py::object> input_error;
  input_error.call_once_and_store_result(
      [&]() { return py::exception<bimcap::InputError>(m, "InputError", PyExc_ValueError); });
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const bimcap::InputError& e) {
      // A message may quote bytes from a damaged file: never let them turn into a
      // UnicodeDecodeError; undecodable bytes are shown as \xNN.
      const std::string what = e.what();
      PyObject* message = PyUnicode_DecodeUTF8(what.data(), static_cast<Py_ssize_t>(what.size()),
                                               "backslashreplace");
      if (message == nullptr) {
        PyErr_Clear();
        py::set_error(input_error.get_stored(), "invalid input");
        return;
      }
      // The exception carries the culprit's name as `field` ("" when none).
      PyObject* type = input_error.get_stored().ptr();
      PyObject* exc = PyObject_CallOneArg(type, message);
      Py_DECREF(message);
      if (exc == nullptr) return;  // the call set its own error
      PyObject* field = PyUnicode_DecodeUTF8(
          e.field().data(), static_cast<Py_ssize_t>(e.field().size()), "backslashreplace");
      if (field != nullptr) {
        PyObject_SetAttrString(exc, "field", field);
        Py_DECREF(field);
      }
      PyErr_Clear();
      PyErr_SetObject(type, exc);
      Py_DECREF(exc);
    }
  });
  m.attr("PROBLEM_FILE_VERSION") = bimcap::kProblemFileVersion;
  bimcap::python::BindCostFunctions(m);
  bimcap::python::BindProblemFile(m);
  bimcap::python::BindRaster(m);
  bimcap::python::BindSolver(m);
}
