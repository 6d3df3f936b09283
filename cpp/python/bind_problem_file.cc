// Problem files from Python through the C++ reader and writer (the only implementation;
// bimcap.optimize.problem_file wraps them).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bimcap/problem_file.h"
#include "python/arrays.h"

namespace bimcap::python {

void BindProblemFile(py::module_& m) {
  m.def(
      "read_problem_file",
      [](const std::string& path) {
        ProblemFile file;
        {
          py::gil_scoped_release release;
          file = ReadProblemFile(path);
        }
        return py::make_tuple(ProblemToDict(file.problem), OptionsToDict(file.options));
      },
      py::arg("path"),
      "Read and validate a problem file with the C++ reader: (arrays: dict, options: dict). "
      "Raises bimcap._core.InputError (a ValueError) naming the field on any malformed input.");
  m.def(
      "parse_problem_bytes",
      [](const py::bytes& data) {
        const std::string bytes = data;
        ProblemFile file;
        {
          py::gil_scoped_release release;
          file = ParseProblemFile(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
        }
        return py::make_tuple(ProblemToDict(file.problem), OptionsToDict(file.options));
      },
      py::arg("data"), "As read_problem_file, from the file's bytes (for tests and fuzzing).");
  m.def(
      "write_problem_file",
      [](const std::string& path, const py::dict& arrays, const py::dict& options) {
        std::vector<py::array> keep_alive;
        const ProblemData problem = ProblemFromDict(arrays, &keep_alive);
        const SolverOptions solver_options = OptionsFromDict(options);
        py::gil_scoped_release release;
        WriteProblemFile(path, problem, solver_options);
      },
      py::arg("path"), py::arg("arrays"), py::arg("options"),
      "Write a problem file with the C++ writer (validates first; atomic).");
  m.def(
      "serialize_problem",
      [](const py::dict& arrays, const py::dict& options) {
        std::vector<py::array> keep_alive;
        const ProblemData problem = ProblemFromDict(arrays, &keep_alive);
        const SolverOptions solver_options = OptionsFromDict(options);
        std::vector<uint8_t> bytes;
        {
          py::gil_scoped_release release;
          bytes = SerializeProblem(problem, solver_options);
        }
        return py::bytes(reinterpret_cast<const char*>(bytes.data()), bytes.size());
      },
      py::arg("arrays"), py::arg("options"),
      "A problem file's bytes (validates first), as write_problem_file would write them.");
  m.def(
      "describe_problem_file",
      [](const std::string& path) { return DescribeProblemFile(ReadProblemFile(path)); },
      py::arg("path"), "The text of bimcap_solve --info.");
}

}  // namespace bimcap::python
