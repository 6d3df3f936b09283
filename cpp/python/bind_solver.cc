// bimcap._core.solve and the option helpers.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bimcap/solver.h"
#include "python/arrays.h"

namespace bimcap::python {

void BindSolver(py::module_& m) {
  m.def(
      "solve",
      [](const py::dict& arrays, const py::dict& options) {
        std::vector<py::array> keep_alive;
        const ProblemData problem = ProblemFromDict(arrays, &keep_alive);
        const SolverOptions solver_options = OptionsFromDict(options);
        SolveResult result;
        {
          // The arrays are held by keep_alive; nothing below touches a Python object.
          py::gil_scoped_release release;
          result = Solve(problem, solver_options);
        }
        const int64_t n = problem.num_poses();
        py::dict out;
        out["poses"] = CopyToNumpy<double>(result.poses.data(), {n, 7});
        out["planes"] = CopyToNumpy<double>(result.planes.data(), {result.num_planes, 4});
        out["track_points"] = CopyToNumpy<double>(
            result.track_points.data(), {static_cast<py::ssize_t>(result.track_points.size() / 3), 3});
        out["wall_segment"] = CopyToNumpy<int>(
            result.wall_segment.data(), {static_cast<py::ssize_t>(result.wall_segment.size())});
        out["column_segment"] = CopyToNumpy<int>(
            result.column_segment.data(), {static_cast<py::ssize_t>(result.column_segment.size())});
        if (result.covariance.empty()) {
          out["covariance"] = py::none();
        } else {
          out["covariance"] = CopyToNumpy<double>(result.covariance.data(), {n, 6, 6});
        }
        // The same JSON that bimcap_solve writes, so that both report identically.
        out["summary"] = py::module_::import("json").attr("loads")(SummaryToJson(result.summary));
        return out;
      },
      py::arg("arrays"), py::arg("options"),
      R"doc(Solve one problem given as dense arrays.

Parameters
----------
arrays : dict[str, numpy.ndarray]
    The problem arrays of docs/architecture.md ("Solver problem"), float64 or int32 exactly as
    listed, C-contiguous. ``poses``, ``timestamps``, ``pose_fixed``, ``cameras`` and
    ``frame_camera`` are required; every other array may be left out (empty term).
options : dict[str, object]
    Flat solver options (``option_keys()``), e.g. ``{"weighting": "PAPER", "floor.enabled": 0}``.

Returns
-------
dict with ``poses`` (N, 7) refined world_from_cam in TUM order, ``planes`` (Q, 4) (FACaP mode:
(2, 4) fitted floor / ceiling planes), ``track_points`` (P, 3), ``wall_segment`` (W,) and
``column_segment`` (W',) int32 final associations (-1: none), ``covariance`` (N, 6, 6) in the
tangent space [dt, dtheta] or None, and ``summary`` (a dict, the JSON of bimcap_solve).

Raises
------
TypeError
    An array is not a numpy array or has the wrong dtype.
ValueError
    Wrong shape, not C-contiguous, a NaN, an index out of range, a bad option
    (``bimcap._core.InputError`` derives from ValueError).

The GIL is released while Ceres runs.)doc");

  m.def("default_options", []() { return OptionsToDict(SolverOptions()); },
        "The default solver options as a dict of str → str.");
  m.def(
      "check_options", [](const py::dict& options) { return OptionsToDict(OptionsFromDict(options)); },
      py::arg("options"),
      "Validate flat options (ValueError naming the key on error); returns them normalised.");
  m.def("option_keys", &OptionKeys, "Every option key the core understands.");
  m.def(
      "validate_problem",
      [](const py::dict& arrays) {
        std::vector<py::array> keep_alive;
        ValidateProblem(ProblemFromDict(arrays, &keep_alive));
      },
      py::arg("arrays"), "Validate problem arrays as solve() does; raises on the first error.");
}

}  // namespace bimcap::python
