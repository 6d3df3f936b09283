"""What a refinement run does: method, terms, weighting, front-end sources, solver settings.

A :class:`RefineConfig` comes from defaults, a TOML file (``bimcap refine --config run.toml``) or
command-line flags, in that order of precedence (flags win). ``bimcap refine --print-config``
prints every setting of a run, solver and registration options included, as a TOML file that
``--config`` reads back. The TOML file holds the same keys as the dataclass, with a ``[solver]``
table (``bimcap.optimize.SolverOptions`` fields, terms as tables, e.g. ``[solver.wall]
sigma = 0.03``), a ``[registration]`` table (``bimcap.registration.CoarseOptions`` fields) and a
``[features]`` table (``bimcap.features.SiftOptions`` fields), a ``[matching]`` table
(``bimcap.features.MatchOptions`` fields)::

    method = "bimcap"          # or "facap"
    terms = "G+F+W+Co+Ce"
    weighting = "robust"       # or "paper": the solver preset
    loss = "cauchy"
    completion = "linear"      # linear | classical | onnx | hybrid | ground_truth
    segmentation = "geometric" # geometric | disk | onnx | ground_truth
    window = 3
    colmap = "images"          # images | model | off: the COLMAP workspace colmap/
    rerun = false              # true: also write run.rrd, a Rerun recording (rerun extra)
    [solver]
    association_gate = 0.5
    [registration]
    xy_range_m = 2.0
    [features]
    backend = "opencv"         # or "pycolmap", "orb" (binary features, ~10x cheaper)
    [matching]
    ransac_min_trials = 100    # pycolmap's own count; the default 10 is ~2.5x cheaper
    [geometric]
    work_width = 258           # the geometric segmenter's working resolution (pixels across)

The front end's per-frame work can run on Dask (``executor = "dask"``, ``bimcap refine --dask``)
with a ``[dask]`` table (``bimcap.frontend.ExecutorOptions``; docs/dask.md)::

    executor = "dask"
    [dask]
    scheduler = "tcp://10.0.0.5:8786"  # a running cluster; absent: a LocalCluster on this machine
    workers = 2                        # LocalCluster worker processes (default: workers / cores)
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

from bimcap.errors import BimcapError, InputError
from bimcap.methods import CompletionMethod, ExecutorKind


class PipelineError(BimcapError):
    """A pipeline step failed (the message says which); the CLI exits with status 3."""

    exit_code = 3


class ConfigError(InputError):
    """A configuration file or flag that cannot be used (names the file and the key)."""


class Method(str, Enum):
    """Which method's objective to build."""

    BIMCAP = "bimcap"  #: BIM planes for F/Ce, floor plan for W/Co (this package's method)
    FACAP = "facap"  #: FACaP: G + a floor plane fitted to the scan + W, the peers' weighting


#: The depth source of a run is a completion method (``bimcap.methods``); the old name.
DepthSource = CompletionMethod


class LabelSource(str, Enum):
    """Where the semantic labels come from."""

    GEOMETRIC = "geometric"  #: the built-in no-weights segmenter
    DISK = "disk"  #: label images (or BIMCaP-style masks) from a folder
    ONNX = "onnx"  #: any ONNX segmentation model with a class map
    GROUND_TRUTH = "ground_truth"  #: the sequence's labels/ (simulated; noisy with --label-noise)


class ColmapExport(str, Enum):
    """What a refine run writes into ``colmap/`` (``bimcap.pipeline.colmap_export``)."""

    OFF = "off"  #: nothing
    MODEL = "model"  #: the sparse model alone (``sparse/0``); its images are the raw ones
    IMAGES = "images"  #: the model and the undistorted images it describes (``images/``)


class GlobalAlignMode(str, Enum):
    """When to place the initial trajectory in the BIM first (``bimcap.registration.
    global_align``): a trajectory in a SLAM system's own frame."""

    AUTO = "auto"  #: when most initial cameras lie outside the building's free space
    ON = "on"  #: always (``--global-align``)
    OFF = "off"  #: never (``--no-global-align``)


#: The values of ``loss`` and ``geometric_mode`` (``bimcap.optimize.Loss`` / ``GeometricMode``).
LOSSES = ("huber", "cauchy", "soft_l1", "arctan", "tukey", "none")
GEOMETRIC_MODES = ("point", "reprojection", "landmark")

#: The terms of each method's full objective.
FULL_TERMS = {Method.BIMCAP: "G+F+W+Co+Ce", Method.FACAP: "G+F+W"}
#: The peers' filter on matches for FACaP runs (m between the two back-projected points).
FACAP_MATCH_DISTANCE_M = 0.4


@dataclass
class RefineConfig:
    """Settings of :func:`bimcap.pipeline.refine.refine`.

    Attributes
    ----------
    method: BIMCaP or FACaP (FACaP: PAPER weighting, F plane fitted to the scan, no Co/Ce).
    terms: the terms switched on, e.g. ``"G+F+W+Co+Ce"`` (None: the method's full set).
    weighting: the solver preset (``bimcap.optimize.Preset``): ``"robust"`` (noise scales +
        robust losses) or ``"paper"`` (the peers' λ-weighted means, plain L2, G as the point
        error). None: robust for BIMCaP, paper for FACaP. Every solver default is the preset's.
    loss: robust loss of each of the paper's terms in robust weighting (``huber``, ``cauchy``,
        ``soft_l1``, ``arctan``, ``tukey``, ``none``). None: the preset's, Cauchy: completed
        depth and estimated labels have heavy-tailed errors (measured on the demo world: Huber
        leaves 1.4 m / 28°, Cauchy 2.7 cm / 0.36° on the same observations).
    geometric_mode: ``point`` (FACaP's point error), ``reprojection`` (the robust preset's: a
        depth error moves the point along the ray, which barely moves its reprojection) or
        ``landmark``. None: the preset's. FACaP runs always use ``point``.
    completion, completion_model: dense-depth source; the ONNX model path for onnx / hybrid.
        Linear interpolation by default: on the demo world the classical (Ku-style, dilation of
        the nearest return) completion biases depth towards the camera, which moved the refined
        cameras 1.9 cm forward on average (ATE_pos 2.7 cm vs 1.15 cm with linear, Exp 2).
    segmentation, segmentation_model, labels_dir: label source; the ONNX model or label folder.
    coarse: run the coarse registration to the floor plan before the bundle adjustment. None
        (default): on for BIMCaP (it levels each frame on its floor, finds its yaw on the walls,
        tracks the translation, and returns the poses unchanged when the drift is already
        small), off for FACaP (the peers' method has none).
    rotation_first: the first solver stage refines rotations first (translations held), then
        translations (rotations held), then both: the paper's Exp. 3 remedy. Off by default:
        on the demo world (Exp. 1–3, seeds 1–3) it reached the same 1.1 cm / 0.35° in 8 of 9
        runs, missed one (Exp. 3 seed 1: 0.27 m / 2.5°) and took 1–3× as long; the joint
        solve invents no translation here (Exp. 3: 1.1 cm).
    staged: before the solve with every term, solve with the BIM terms only (F, Ce, W, Co) and
        robust-loss scales widened 4× (``bimcap.registration.Schedule.default``). Off by
        default: without G each frame fits the plan on its own and corridor frames slide, so
        on the demo world it failed 3 of 9 runs (0.25–0.79 m) that the single solve converges.
    window: match each frame with its next ``window`` frames. 3 (the default since
        2026-11-28; 4 before) matches 3 pairs a frame instead of 4; with the verification's
        Sampson refinement off (the same day) the front end is 2–4 ms a frame cheaper at
        516×386, and BIMCaP moved by at most +0.0035 cm (standard), +0.0069 cm (unseen seeds)
        and +0.024 cm / +0.003° (hard) (docs/speed.md, "Cheaper defaults"). 2 halves the
        matching and the verification against 4 and moved BIMCaP's rotation by up to +0.002°
        on four worlds: not the default.
    max_match_distance: the peers' filter on matches (metres between the two back-projected
        points under the initial poses; the paper used 0.4). None (default) keeps every
        geometrically verified match: with per-frame rotation drift the filter drops most of them.
    solve_match_distance: the same filter applied each time a solver problem is built, at that
        stage's poses (m; 0: off). None (default): 0.4 for FACaP (the peers' filter), off for
        BIMCaP.
    workers: front-end processes, and the global alignment's threads (None: all cores).
    executor: where the front end's per-frame and per-pair jobs run: ``local`` (a process pool
        of ``workers``) or ``dask`` (a Dask cluster, the ``dask`` table). The solve always runs
        in this process; both give the same front end bit for bit.
    dask: the Dask executor's settings (``bimcap.frontend.ExecutorOptions.from_table``):
        ``scheduler`` (``tcp://HOST:PORT`` of a running cluster; absent: a LocalCluster on
        this machine), ``workers`` (the LocalCluster's processes), ``threads_per_worker``,
        ``connect_timeout_s``, ``worker_timeout_s``.
    lidar_nan: what a LiDAR scan with NaN / inf points does: ``"raise"`` (default: stop, naming
        the scan file and frame) or ``"drop"`` (drop those points; a scan with no valid point
        gives its frame no depth).
    max_lost_fraction: the largest share of the IFC's building elements that may be lost to a
        damaged file (unreadable, missing, or without geometry) before the BIM reference is
        refused (``bimcap.bim.ingest.load_model``); any loss below it is a loud warning.
    cache_dir: root of the shared cache (``bimcap.io.cache``: the BIM reference of each IFC
        content, reused by runs with other output directories). None: ``$BIMCAP_CACHE_DIR``,
        else ``$XDG_CACHE_HOME/bimcap``, else ``~/.cache/bimcap``; ``"off"``: no shared cache.
    solver: overrides of ``bimcap.optimize.SolverOptions`` fields (nested dicts for terms),
        applied after the preset, ``loss`` and ``geometric_mode``.
    registration: overrides of ``bimcap.registration.CoarseOptions`` fields (the coarse stage).
    features: overrides of ``bimcap.features.SiftOptions`` fields (the front end's keypoints).
    matching: overrides of ``bimcap.features.MatchOptions`` fields (each pair's descriptor
        matching and geometric verification, e.g. ``ransac_min_trials``).
    geometric: overrides of ``bimcap.segmentation.geometric.GeometricOptions`` fields (the
        geometric segmenter of ``segmentation = "geometric"``, e.g. its ``work_width``).
    colmap: the COLMAP model of the refined reconstruction in ``colmap/`` (:class:`ColmapExport`):
        ``images`` (default: the model and undistorted copies of the images), ``model`` (the
        model alone: no image copies, for long sequences) or ``off``.
    rerun: also write the run as a Rerun recording, ``run.rrd`` (``bimcap.pipeline.
        rerun_export``; the ``rerun`` extra), at the end of the run. Off by default.
    global_align: ``"auto"`` (default: when fewer than 30 % of the initial cameras lie in the
        building's free space, log it and align), ``"on"`` or ``"off"`` (TOML ``true`` /
        ``false`` read as on / off): estimate ``world_from_slam`` before the coarse stage.
    lidar_scan: the LiDAR scan outside the camera's view gives wall, floor and ceiling samples
        too (``bimcap.fusion.scan``): every frame sees the walls all around it, not only the
        60–70° its camera sees. None (default): on for BIMCaP, off for FACaP (the peers' method
        samples the image alone).
    scan_sigma_m: with the LiDAR scan's samples, the noise scale (metres) of the BIM terms
        (wall, column, floor, ceiling) in one more solve after the last stage has converged with
        every scan sample at the preset's scale (straight from the schedule's poses it settles
        off: SampleHouse4 Exp 2 0.85 cm, 0.26 cm in two steps): 10 cm voxel means of a scan
        sit within a centimetre or two of their surface, and at the presets' 5 cm the Cauchy
        loss still lets furniture and fittings 5–50 cm off a wall pull the frames (0.6 cm on
        the Duplex model from the ground truth).
        None keeps the preset's.
    accept_ambiguous: when the global alignment is ambiguous (the second-best placement scores
        nearly as well as the best), take the best anyway instead of refusing (flagged in
        ``result.json``).
    datum: with ``refine --deviations``, the elements declared as built right
        (:mod:`bimcap.deviations.datum` selectors: IFC GUIDs, ``name:PATTERN``,
        ``class:IfcClass``; TOML ``datum = ["class:IfcColumn", "2O2Fr$t4X7Zf8NOew3FLOH"]``):
        the deviations are measured after the rigid correction that puts them on the design.
        Empty (default): relative to the refined poses.
    datum_fit: ``"frames"`` (default: the rigid correction, then one per frame fitted jointly
        with the other elements' offsets) or ``"rigid"`` (:class:`bimcap.deviations.datum.
        DatumFitMode`).
    map_storey: crop ``map_refined.ply`` to this storey of the IFC (by name: from 0.3 m under
        its elevation to the next storey's); None (default) keeps every return. Checked
        against the BIM reference's storeys before the front end runs.
    """

    method: Method = Method.BIMCAP
    terms: str | None = None
    weighting: str | None = None
    loss: str | None = None
    geometric_mode: str | None = None
    completion: CompletionMethod = CompletionMethod.LINEAR
    completion_model: str | None = None
    segmentation: LabelSource = LabelSource.GEOMETRIC
    segmentation_model: str | None = None
    labels_dir: str | None = None
    coarse: bool | None = None
    rotation_first: bool = False
    staged: bool = False
    samples: str = "dense"
    window: int = 3
    max_match_distance: float | None = None
    solve_match_distance: float | None = None
    workers: int | None = None
    executor: ExecutorKind = ExecutorKind.LOCAL
    dask: dict[str, Any] = field(default_factory=dict)
    lidar_nan: str = "raise"
    max_lost_fraction: float = 0.02
    cache_dir: str | None = None
    solver: dict[str, Any] = field(default_factory=dict)
    registration: dict[str, Any] = field(default_factory=dict)
    features: dict[str, Any] = field(default_factory=dict)
    matching: dict[str, Any] = field(default_factory=dict)
    geometric: dict[str, Any] = field(default_factory=dict)
    colmap: ColmapExport = ColmapExport.IMAGES
    rerun: bool = False
    global_align: GlobalAlignMode = GlobalAlignMode.AUTO
    datum: list[str] = field(default_factory=list)
    datum_fit: str = "frames"
    map_storey: str | None = None
    accept_ambiguous: bool = False
    lidar_scan: bool | None = None
    scan_sigma_m: float | None = 0.02

    def __post_init__(self) -> None:
        if isinstance(self.global_align, bool):
            self.global_align = GlobalAlignMode.ON if self.global_align else GlobalAlignMode.OFF
        try:
            self.global_align = GlobalAlignMode(self.global_align)
        except ValueError:
            raise ConfigError(f"global_align must be auto, on or off, got {self.global_align!r}",
                              field="global_align") from None
        if self.lidar_scan is not None and not isinstance(self.lidar_scan, bool):
            raise ConfigError(f"lidar_scan must be true or false, got {self.lidar_scan!r}",
                              field="lidar_scan")
        if self.scan_sigma_m is not None and not (
                isinstance(self.scan_sigma_m, (int, float)) and not isinstance(
                    self.scan_sigma_m, bool) and 0 < self.scan_sigma_m < 1):
            raise ConfigError(f"scan_sigma_m must be a noise scale in metres in (0, 1), got "
                              f"{self.scan_sigma_m!r}", field="scan_sigma_m")
        if not isinstance(self.rerun, bool):
            raise ConfigError(f"rerun must be true or false, got {self.rerun!r}", field="rerun")
        if not isinstance(self.accept_ambiguous, bool):
            raise ConfigError(f"accept_ambiguous must be true or false, got "
                              f"{self.accept_ambiguous!r}", field="accept_ambiguous")
        try:
            self.colmap = ColmapExport(self.colmap)
        except ValueError:
            raise ConfigError(f"colmap must be one of {[c.value for c in ColmapExport]}, got "
                              f"{self.colmap!r}", field="colmap") from None
        try:
            self.method = Method(self.method)
            self.completion = CompletionMethod(self.completion)
            self.segmentation = LabelSource(self.segmentation)
        except ValueError as exc:
            raise ConfigError(str(exc), field="method/completion/segmentation") from None
        try:
            self.executor = ExecutorKind(self.executor)
        except ValueError:
            raise ConfigError(f"executor must be local or dask, got {self.executor!r}",
                              field="executor") from None
        if not isinstance(self.dask, dict):
            raise ConfigError("dask must be a table of the Dask executor's settings",
                              field="dask")
        if self.weighting is not None and self.weighting.lower() not in ("robust", "paper"):
            raise ConfigError(f"weighting must be robust or paper, got {self.weighting!r}",
                              field="weighting")
        if self.completion.needs_model and not self.completion_model:
            raise ConfigError(f"completion {self.completion.value} needs completion_model",
                              field="completion_model")
        if self.segmentation is LabelSource.ONNX and not self.segmentation_model:
            raise ConfigError("segmentation onnx needs segmentation_model",
                              field="segmentation_model")
        if self.segmentation is LabelSource.DISK and not self.labels_dir:
            raise ConfigError("segmentation disk needs labels_dir", field="labels_dir")
        if self.window < 1:
            raise ConfigError(f"window must be >= 1, got {self.window}", field="window")
        if self.samples not in ("dense", "returns"):
            raise ConfigError(f"samples must be dense or returns, got {self.samples!r}",
                              field="samples")
        if self.workers is not None and self.workers < 1:
            raise ConfigError(f"workers must be >= 1, got {self.workers}", field="workers")
        if self.max_match_distance is not None and not self.max_match_distance > 0:
            raise ConfigError(f"max_match_distance must be > 0 m, got {self.max_match_distance}",
                              field="max_match_distance")
        if self.solve_match_distance is not None and not self.solve_match_distance >= 0:
            raise ConfigError("solve_match_distance must be >= 0 m (0: off), got "
                              f"{self.solve_match_distance}", field="solve_match_distance")
        if self.lidar_nan not in ("raise", "drop"):
            raise ConfigError(f"lidar_nan must be raise or drop, got {self.lidar_nan!r}",
                              field="lidar_nan")
        if not 0.0 <= self.max_lost_fraction <= 1.0:
            raise ConfigError(f"max_lost_fraction must be in [0, 1], got {self.max_lost_fraction}",
                              field="max_lost_fraction")
        if self.cache_dir is not None and not isinstance(self.cache_dir, str):
            raise ConfigError("cache_dir must be a directory path or \"off\"", field="cache_dir")
        if not isinstance(self.solver, dict):
            raise ConfigError("solver must be a table of SolverOptions fields", field="solver")
        if not isinstance(self.registration, dict):
            raise ConfigError("registration must be a table of CoarseOptions fields",
                              field="registration")
        if not isinstance(self.features, dict):
            raise ConfigError("features must be a table of SiftOptions fields", field="features")
        if not isinstance(self.matching, dict):
            raise ConfigError("matching must be a table of MatchOptions fields", field="matching")
        if not isinstance(self.geometric, dict):
            raise ConfigError("geometric must be a table of GeometricOptions fields",
                              field="geometric")
        if isinstance(self.datum, str) or not isinstance(self.datum, (list, tuple)):
            raise ConfigError(f"must be a list of selectors, got {self.datum!r}", field="datum")
        from bimcap.deviations.datum import DatumError, DatumSpec

        try:
            DatumSpec.parse(self.datum, "datum", self.datum_fit)
        except DatumError as exc:
            raise ConfigError(exc.message, field=exc.field or "datum") from None
        self.datum = list(self.datum)
        if self.map_storey is not None and (not isinstance(self.map_storey, str)
                                            or not self.map_storey.strip()):
            raise ConfigError(f"must be a storey name, got {self.map_storey!r}",
                              field="map_storey")
        for name, value, allowed in (("loss", self.loss, LOSSES),
                                     ("geometric_mode", self.geometric_mode, GEOMETRIC_MODES)):
            if value is not None and value.lower() not in allowed:
                raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {value!r}",
                                  field=name)

    @property
    def effective_terms(self) -> str:
        return self.terms or FULL_TERMS[self.method]

    @property
    def effective_lidar_scan(self) -> bool:
        """Whether the scan outside the camera's view gives W / F / Ce samples."""
        if self.lidar_scan is not None:
            return bool(self.lidar_scan)
        return self.method is Method.BIMCAP

    @property
    def effective_coarse(self) -> bool:
        if self.coarse is not None:
            return bool(self.coarse)
        return self.method is Method.BIMCAP

    @property
    def effective_weighting(self) -> str:
        if self.weighting:
            return self.weighting.lower()
        return "paper" if self.method is Method.FACAP else "robust"

    @property
    def effective_solve_match_distance(self) -> float | None:
        """The solve-time match filter in metres, None when off."""
        d = self.solve_match_distance
        if d is None:
            d = FACAP_MATCH_DISTANCE_M if self.method is Method.FACAP else 0.0
        return d if d > 0 else None

    def with_(self, **changes: Any) -> RefineConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["method"] = self.method.value
        d["completion"] = self.completion.value
        d["segmentation"] = self.segmentation.value
        d["executor"] = self.executor.value
        d["colmap"] = self.colmap.value
        d["global_align"] = self.global_align.value
        d["effective_terms"] = self.effective_terms
        d["effective_weighting"] = self.effective_weighting
        d["effective_coarse"] = self.effective_coarse
        d["effective_lidar_scan"] = self.effective_lidar_scan
        d["effective_solve_match_distance"] = self.effective_solve_match_distance
        return d

    @classmethod
    def from_toml(cls, path: str | PathLike[str], **overrides: Any) -> RefineConfig:
        """Read a TOML file; ``overrides`` (non-None values) win over the file."""
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError("no such file", p) from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"not valid TOML: {exc}", p) from None
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown key(s) {unknown}; known: {sorted(known)}", p, unknown[0])
        data.update({k: v for k, v in overrides.items() if v is not None})
        try:
            return cls(**data)
        except ConfigError as exc:
            raise ConfigError(str(exc), p) from None
        except TypeError as exc:
            raise ConfigError(str(exc), p) from None


def options_from_table(cls: Any, table: dict[str, Any], section: str,
                       error: type[Exception]) -> Any:
    """``cls(**table)`` for an options dataclass whose defaults give each field's type (bool,
    int, float, str or a str enum; a field whose default is None takes an int). A key that is
    not a field, a value of the wrong type, or one that ``cls`` refuses (``error``, with
    ``message`` and ``field``) raises ConfigError naming ``<section>.<key>``."""
    defaults = cls()
    kinds = {f.name: type(getattr(defaults, f.name)) for f in fields(cls)}
    values: dict[str, Any] = {}
    for key, value in table.items():
        kind = kinds.get(key)
        where = f"{section}.{key}"
        if kind is None:
            raise ConfigError(f"unknown option; known: {sorted(kinds)}", field=where)
        if issubclass(kind, Enum):
            try:
                values[key] = kind(value)
            except ValueError:
                raise ConfigError(f"must be one of {[m.value for m in kind]}, got {value!r}",
                                  field=where) from None
            continue
        ok = (isinstance(value, bool) if kind is bool else
              isinstance(value, str) if kind is str else
              isinstance(value, int) and not isinstance(value, bool)
              if kind in (int, type(None)) else
              isinstance(value, (int, float)) and not isinstance(value, bool))
        if not ok:
            name = "int" if kind is type(None) else kind.__name__
            raise ConfigError(f"must be {name}, got {value!r}", field=where)
        values[key] = float(value) if kind is float else value
    try:
        return cls(**values)
    except error as exc:
        bad = getattr(exc, "field", None)
        raise ConfigError(getattr(exc, "message", str(exc)),
                          field=f"{section}.{bad}" if bad else section) from None


def toml_text(settings: dict[str, Any], header: str = "") -> str:
    """``settings`` as TOML that :meth:`RefineConfig.from_toml` reads back: scalars first, then
    one table per dict (one level of sub-tables: ``[solver.wall]``); None values are written
    as comments (TOML has no null)."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, Enum):
            v = v.value
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'

    def table(name: str, d: dict[str, Any]) -> list[str]:
        lines = [f"[{name}]"] if name else []
        for k, v in d.items():
            if v is None:
                lines.append(f"# {k}: not set")
            elif not isinstance(v, dict):
                lines.append(f"{k} = {value(v)}")
        for k, v in d.items():
            if isinstance(v, dict):
                lines += ["", *table(f"{name}.{k}" if name else k, v)]
        return lines

    out = [f"# {line}" for line in header.splitlines()]
    return "\n".join([*out, *table("", settings)]) + "\n"
