"""``bimcap experiment``: the paper's evaluation (Tables 1 and 2) on the synthetic world.

For each drift preset (``exp1``, ``exp2``, ``exp3``) and seed, the same simulated sequence gets a
new drifted initial trajectory; the front end runs once per (preset, seed) and every ablation row
of the paper's Table 1 is solved on it:

* BIMCaP: G+F+W+Co+Ce, G+F+W+Ce, G+F+W, F, W+Co, Ce
* FACaP:  G+F+W, G, F, W

Each row reports MME, MPV, NND (against the map built with the ground-truth poses), ATE_pos,
ATE_rot and the yaw/pitch/roll RMSE, averaged over the seeds. Outputs: ``results.csv`` (one line
per run), ``table1.md`` (the layout of the paper's Table 1, per preset) and ``table2.md`` (Table 2:
Exp. 2 and 3 with yaw/pitch/roll), both with the paper's numbers beside for reference, and a plot.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from bimcap.logs import quieted
from bimcap.pipeline.config import Method, RefineConfig
from bimcap.pipeline.paper_reference import table1_row, table2_row

#: The paper's ablation rows: (method, terms).
ABLATIONS: tuple[tuple[Method, str], ...] = (
    (Method.BIMCAP, "G+F+W+Co+Ce"),
    (Method.BIMCAP, "G+F+W+Ce"),
    (Method.BIMCAP, "G+F+W"),
    (Method.BIMCAP, "F"),
    (Method.BIMCAP, "W+Co"),
    (Method.BIMCAP, "Ce"),
    (Method.FACAP, "G+F+W"),
    (Method.FACAP, "G"),
    (Method.FACAP, "F"),
    (Method.FACAP, "W"),
)

_log = logging.getLogger(__name__)

COLUMNS = ("mme", "mpv", "nnd_m", "ate_pos_m", "ate_rot_deg", "yaw_deg", "pitch_deg", "roll_deg")
#: With ``ExperimentOptions.deviations``: the scan-vs-BIM deviations under each row's poses,
#: scored against the as-built's truth (:mod:`bimcap.deviations.scoring`).
DEVIATION_COLUMNS = ("dev_recall", "dev_false_alarm_rate", "dev_missing_recall",
                     "dev_offset_rmse_m")


@dataclass(frozen=True)
class ExperimentOptions:
    """What to run.

    Attributes
    ----------
    experiments: drift presets.
    seeds: drift seeds (the world and the walk use ``world_seed``).
    ablations: (method, terms) rows; default the paper's Table 1.
    preset, frames, scale, world_seed: the synthetic world (as in ``bimcap demo``).
    config: base settings of every run (sources, losses); method/terms are set per row.
    deviations: also score the scan-vs-BIM deviations of every row (:data:`DEVIATION_COLUMNS`).
    """

    experiments: tuple[str, ...] = ("exp1", "exp2", "exp3")
    seeds: tuple[int, ...] = (1, 2, 3)
    ablations: tuple[tuple[Method, str], ...] = ABLATIONS
    preset: str = "demo"
    frames: int = 60
    scale: float = 0.25
    world_seed: int = 0
    config: RefineConfig = field(default_factory=RefineConfig)
    deviations: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "deviations": self.deviations,
            "experiments": list(self.experiments),
            "seeds": list(self.seeds),
            "ablations": [[m.value, t] for m, t in self.ablations],
            "preset": self.preset,
            "frames": self.frames,
            "scale": self.scale,
            "world_seed": self.world_seed,
            "config": self.config.to_dict(),
        }


@dataclass
class RunRecord:
    """One solved row of one (experiment, seed)."""

    experiment: str
    seed: int
    method: str
    terms: str
    values: dict[str, float]
    seconds: float
    ok: bool = True
    message: str = ""
    coarse_seconds: float = 0.0  #: of ``seconds``, the coarse registration stage

    def to_dict(self) -> dict[str, Any]:
        return {"experiment": self.experiment, "seed": self.seed, "method": self.method,
                "terms": self.terms, **self.values, "seconds": self.seconds,
                "coarse_seconds": self.coarse_seconds, "ok": self.ok, "message": self.message}


def _values(tm: Any, mm: Any) -> dict[str, float]:
    nan = float("nan")
    return {
        "mme": nan if mm is None else mm.mme,
        "mpv": nan if mm is None else mm.mpv,
        "nnd_m": nan if mm is None else mm.nnd_m,
        "ate_pos_m": tm.ate_pos_m.rmse,
        "ate_rot_deg": tm.ate_rot_deg.rmse,
        "yaw_deg": tm.yaw_rmse_deg,
        "pitch_deg": tm.pitch_rmse_deg,
        "roll_deg": tm.roll_rmse_deg,
    }


def run_experiment(out_dir: str | Path, opts: ExperimentOptions | None = None,
                   quiet: bool | None = None) -> list[RunRecord]:
    """Run every (experiment, seed, ablation) and write the tables into ``out_dir``.

    Each run is logged at INFO on this module's logger, the stages of its solves at DEBUG;
    ``quiet`` is deprecated (:func:`bimcap.logs.quieted`).
    """
    with quieted(quiet):
        return _run_experiment(out_dir, opts)


def _run_experiment(out_dir: str | Path, opts: ExperimentOptions | None) -> list[RunRecord]:
    """:func:`run_experiment`."""
    from bimcap.dataset import add_trajectory, read_sequence
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world
    from bimcap.pipeline.refine import evaluate_run, prepare, solve_prepared
    from bimcap.sim.drift import DriftParams, apply_drift

    o = opts or ExperimentOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world_opts = DemoOptions(preset=o.preset, seed=o.world_seed, frames=o.frames, scale=o.scale)
    design, built = make_world(out, world_opts)
    seq_dir = make_sequence(out, design, built, world_opts)
    gt = read_sequence(seq_dir).trajectory("gt")
    scorer = DeviationScorer(read_sequence(seq_dir), design, built) if o.deviations else None
    records: list[RunRecord] = []
    for exp in o.experiments:
        for seed in o.seeds:
            name = f"init_{exp}_s{seed}"
            seq = read_sequence(seq_dir)
            if not seq.has_trajectory(name):
                drift = apply_drift(gt, DriftParams.from_preset(exp, seed=seed))
                add_trajectory(seq, name, drift.init, header=f"bimcap drift {exp} seed {seed}")
                seq = read_sequence(seq_dir)
            _log.info(f"{exp} seed {seed}: front end")
            prepared = prepare(seq, design, seq.trajectory_path(name), o.config,
                               out / "runs" / f"{exp}_s{seed}")
            tm, mm = evaluate_run(prepared, prepared.init, gt)
            values = _values(tm, mm)
            if scorer is not None:
                values.update(scorer(prepared.init.poses))
            records.append(RunRecord(exp, seed, "initial", "-", values, 0.0))
            for method, terms in o.ablations:
                # FACaP rows are the peers' method: no coarse stage in front of them.
                cfg = replace(o.config, method=method, terms=terms, weighting=None,
                              coarse=o.config.effective_coarse and method is Method.BIMCAP)
                t0 = time.perf_counter()
                try:
                    # the stages of every row: only under -v (DEBUG)
                    with quieted(not _log.isEnabledFor(logging.DEBUG)):
                        res = solve_prepared(prepared, cfg)
                    tm, mm = evaluate_run(prepared, res.refined, gt)
                    values = _values(tm, mm)
                    if scorer is not None:
                        values.update(scorer(res.refined.poses))
                    rec = RunRecord(exp, seed, method.value, terms, values,
                                    time.perf_counter() - t0,
                                    coarse_seconds=(res.coarse or {}).get("seconds", 0.0))
                except Exception as exc:  # a failed row is reported, not fatal
                    rec = RunRecord(exp, seed, method.value, terms,
                                    {c: float("nan") for c in COLUMNS},
                                    time.perf_counter() - t0, ok=False, message=str(exc))
                records.append(rec)
                _log.info(f"  {method.value:6} {terms:12} ATE {rec.values['ate_pos_m']:.3f} m / "
                          f"{rec.values['ate_rot_deg']:.2f} deg ({rec.seconds:.1f} s)")
    write_outputs(out, o, records)
    return records


class DeviationScorer:
    """The deviation columns of one pose set: the design ``design`` analysed against the scans of
    ``sequence``, scored against the as-built ``built``'s truth sidecar."""

    def __init__(self, sequence: Any, design: Path, built: Path) -> None:
        from bimcap.deviations.analysis import load_design
        from bimcap.sim.building import truth_path_for
        from bimcap.sim.building_truth import load_building_truth

        self.sequence, self.design = sequence, design
        self.model = load_design(design)
        truth = load_building_truth(truth_path_for(built)).deviations
        if truth is None:
            raise InputError("the as-built has no deviations", truth_path_for(built),
                             "deviations")
        self.truth = truth

    def __call__(self, world_from_cam: np.ndarray) -> dict[str, float]:
        from bimcap.deviations.analysis import analyse_deviations
        from bimcap.deviations.refined_map import load_scans
        from bimcap.deviations.scoring import score_deviations

        scans = load_scans(self.sequence, world_from_cam)
        report = analyse_deviations(self.model, scans, ifc_path=self.design)
        sc = score_deviations(report, self.truth.wall_shifts, self.truth.column_offsets,
                              self.truth.missing)
        return {"dev_recall": sc.recall, "dev_false_alarm_rate": sc.false_alarm_rate,
                "dev_missing_recall": sc.missing_recall, "dev_offset_rmse_m": sc.offset_rmse_m}


def _mean(records: list[RunRecord], key: str) -> float:
    vals = [r.values[key] for r in records if r.ok and math.isfinite(r.values[key])]
    return float(np.mean(vals)) if vals else float("nan")


def aggregate(records: list[RunRecord]) -> dict[tuple[str, str, str], dict[str, float]]:
    """Mean over seeds per (experiment, method, terms)."""
    groups: dict[tuple[str, str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.experiment, r.method, r.terms), []).append(r)
    out = {}
    for key, rs in groups.items():
        out[key] = {c: _mean(rs, c) for c in COLUMNS}
        out[key]["n"] = float(sum(r.ok for r in rs))
    return out


def _f(x: float, d: int = 3) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{d}f}"


def table1_markdown(records: list[RunRecord], experiments: tuple[str, ...]) -> str:
    """The paper's Table 1 layout, one block per experiment, with the paper's Exp. 1 beside."""
    agg = aggregate(records)
    lines = ["# Table 1 — synthetic world (mean over seeds); paper's ConSLAM Exp. 1 in brackets",
             ""]
    for exp in experiments:
        lines += [f"## {exp}", "",
                  "| method | G | F | W | Co | Ce | MME | MPV | NND [m] "
                  "| ATE_pos [m] | ATE_rot [°] |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        keys = [k for k in agg if k[0] == exp]
        keys.sort(key=lambda k: (k[1] != "initial", k[1] != "facap", k[2]))
        for _, method, terms in keys:
            v = agg[(exp, method, terms)]
            used = set(terms.split("+"))
            ticks = " | ".join("✓" if t in used else "–" for t in ("G", "F", "W", "Co", "Ce"))
            paper = (table1_row("FACaP" if method == "facap" else "BIMCaP", terms)
                     if method != "initial" else None)
            if method == "initial":
                from bimcap.pipeline.paper_reference import TABLE1

                paper = TABLE1[1][2:] if exp == "exp1" else None
            def cell(i: int, key: str, d: int = 3, v: dict[str, float] = v,
                     paper: Sequence[float] | None = paper, exp: str = exp) -> str:
                s = _f(v[key], d)
                if paper is not None and exp == "exp1":
                    s += f" [{paper[i]:.{d}f}]"
                return s
            lines.append(f"| {method} | {ticks} | {cell(0, 'mme')} | {cell(1, 'mpv')} | "
                         f"{cell(2, 'nnd_m')} | {cell(3, 'ate_pos_m')} | "
                         f"{cell(4, 'ate_rot_deg', 2)} |")
        lines.append("")
    return "\n".join(lines)


def table2_markdown(records: list[RunRecord]) -> str:
    """The paper's Table 2 layout (Exp. 2 and 3, full objectives), paper numbers in brackets."""
    agg = aggregate(records)
    lines = ["# Table 2 — Exp. 2 and 3 (mean over seeds); paper's ConSLAM numbers in brackets",
             "",
             "| experiment | method | ATE_pos [cm] | ATE_rot [°] | yaw [°] | pitch [°] "
             "| roll [°] |",
             "|---|---|---|---|---|---|---|"]
    for exp in ("exp2", "exp3"):
        for method, terms, paper_name in (("initial", "-", "initial"), ("facap", "G+F+W", "FACaP"),
                                          ("bimcap", "G+F+W+Co+Ce", "BIMCaP")):
            v = agg.get((exp, method, terms))
            if v is None:
                continue
            p = table2_row(exp, paper_name)
            vals = [v["ate_pos_m"] * 100, v["ate_rot_deg"], v["yaw_deg"], v["pitch_deg"],
                    v["roll_deg"]]
            cells = [f"{_f(x, 2)} [{p[i]:.2f}]" if p else _f(x, 2) for i, x in enumerate(vals)]
            lines.append(f"| {exp} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_outputs(out: Path, opts: ExperimentOptions, records: list[RunRecord]) -> None:
    """``results.csv``, ``table1.md``, ``table2.md``, ``experiment.json`` and ``ate.png``."""
    buf = io.StringIO()
    extra = list(DEVIATION_COLUMNS) if opts.deviations else []
    fieldnames = ["experiment", "seed", "method", "terms", *COLUMNS, *extra, "seconds",
                  "coarse_seconds", "ok", "message"]
    w = csv.DictWriter(buf, fieldnames=fieldnames)
    w.writeheader()
    for r in records:
        w.writerow(r.to_dict())
    atomic_write_text(out / "results.csv", buf.getvalue())
    atomic_write_text(out / "table1.md", table1_markdown(records, opts.experiments))
    atomic_write_text(out / "table2.md", table2_markdown(records))
    atomic_write_json(out / "experiment.json", {
        "options": opts.to_dict(),
        "records": [_json_safe(r.to_dict()) for r in records],
    })
    _plot(out / "ate.png", records, opts.experiments)


def _json_safe(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def _plot(path: Path, records: list[RunRecord], experiments: tuple[str, ...]) -> None:
    from matplotlib.figure import Figure

    agg = aggregate(records)
    fig = Figure(figsize=(11, 3.8 * len(experiments)))
    for i, exp in enumerate(experiments):
        keys = [k for k in agg if k[0] == exp]
        names = [f"{m} {t}" for _, m, t in keys]
        for j, (col, unit) in enumerate((("ate_pos_m", "ATE_pos [m]"),
                                         ("ate_rot_deg", "ATE_rot [°]"))):
            ax = fig.add_subplot(len(experiments), 2, 2 * i + j + 1)
            ax.barh(range(len(keys)), [agg[k][col] for k in keys],
                    color=["grey" if k[1] == "initial"
                           else ("tab:orange" if k[1] == "facap" else "tab:blue")
                           for k in keys])
            ax.set_yticks(range(len(keys)), names, fontsize=7)
            ax.set_xlabel(unit)
            ax.set_title(exp)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    atomic_write_bytes(path, buf.getvalue())
