// bimcap._core.solve and the option helpers.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bimcap/solver.h"
#include "bimcap/terms.h"
#include "python/arrays.h"

namespace bimcap::python {

namespace {

// _core.solve.
void BindSolve(py::module_& m) {
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
        out["track_points"] =
            CopyToNumpy<double>(result.track_points.data(),
                                {static_cast<py::ssize_t>(result.track_points.size() / 3), 3});
        for (const auto& [key, segments] : result.segment_of) {
          out[py::str(key + "_segment")] =
              CopyToNumpy<int>(segments.data(), {static_cast<py::ssize_t>(segments.size())});
        }
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
    ``frame_camera`` are required; a term's arrays may be left out (``problem_fields()``): the
    term is then empty.
options : dict[str, object]
    Flat solver options (``option_keys()``), e.g. ``{"weighting": "PAPER", "floor.enabled": 0}``.

Returns
-------
dict with ``poses`` (N, 7) refined world_from_cam in TUM order, ``planes`` (Q, 4) (FACaP mode:
(2, 4) fitted floor / ceiling planes), ``track_points`` (P, 3), ``<key>_segment`` (one per
segment term: ``wall_segment`` (W,), ``column_segment`` (W',)) int32 final associations (-1: none), ``covariance`` (N, 6, 6) in the
tangent space [dt, dtheta] or None, and ``summary`` (a dict, the JSON of bimcap_solve).

Raises
------
TypeError
    An array is not a numpy array or has the wrong dtype.
ValueError
    Wrong shape, not C-contiguous, a NaN, an index out of range, a bad option
    (``bimcap._core.InputError`` derives from ValueError).

The GIL is released while Ceres runs.)doc");
}

// The option helpers: defaults, presets, checks, keys and their specs, the term registry.
void BindOptions(py::module_& m) {
  m.def(
      "default_options", []() { return OptionsToDict(SolverOptions()); },
      "The default solver options as a dict of str → str.");
  m.def(
      "preset_options",
      [](const std::string& name) { return OptionsToDict(SolverOptions::Preset(name)); },
      py::arg("name"),
      "A named preset's options as a dict of str → str (ValueError for an unknown name).");
  m.def("preset_names", &SolverOptions::PresetNames, "The names of the option presets.");
  m.def(
      "check_options",
      [](const py::dict& options) { return OptionsToDict(OptionsFromDict(options)); },
      py::arg("options"),
      "Validate flat options (ValueError naming the key on error); returns them normalised.");
  m.def("option_keys", &OptionKeys, "Every option key the core understands.");
  m.def(
      "option_specs",
      []() {
        py::list out;
        for (const OptionSpec& spec : OptionSpecs()) {
          py::dict d;
          d["key"] = spec.key;
          d["kind"] = spec.kind;
          d["default"] = spec.default_value;
          d["choices"] = spec.choices;
          out.append(d);
        }
        return out;
      },
      "Every option: key, kind (enum / bool / int / float), default (text), choices (enums).");
  m.def(
      "terms",
      []() {
        py::list out;
        for (const TermSpec& spec : Terms()) {
          py::dict d;
          d["name"] = spec.name;
          d["key"] = spec.key;
          d["what"] = spec.what;
          d["doc"] = spec.doc;
          d["paper_term"] = spec.paper_term;
          d["bim_term"] = spec.bim_term;
          py::list arrays;
          for (const ArraySpec& a : spec.arrays) arrays.append(a.name);
          d["arrays"] = arrays;
          py::dict params;
          for (const ParamSpec& p : spec.params) params[p.name] = p.default_value;
          d["params"] = params;
          d["segment_class"] = spec.segment_class;
          d["facap_plane"] = spec.facap_plane;
          d["points"] = spec.points;
          out.append(d);
        }
        return out;
      },
      "The term registry (cpp/bimcap/terms.h), in summary order: name, key, what, doc, "
      "paper_term, bim_term, arrays, params (name → default), segment_class, facap_plane, points.");
  m.def(
      "problem_fields",
      []() {
        py::list out;
        for (const FieldSpec& f : ProblemFields()) {
          out.append(py::make_tuple(f.name, f.dtype == DType::kFloat64 ? "float64" : "int32",
                                    f.cols, f.required, f.term));
        }
        return out;
      },
      "The problem arrays: (name, dtype, columns or 0 for 1-D, required, declaring term key).");
  m.def(
      "validate_problem",
      [](const py::dict& arrays) {
        std::vector<py::array> keep_alive;
        ValidateProblem(ProblemFromDict(arrays, &keep_alive));
      },
      py::arg("arrays"), "Validate problem arrays as solve() does; raises on the first error.");
}

}  // namespace

void BindSolver(py::module_& m) {
  BindSolve(m);
  BindOptions(m);
}

}  // namespace bimcap::python
