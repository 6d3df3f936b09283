"""A datum for the deviations: elements declared as built right, and the rigid correction of the
refined poses that puts them exactly where the design has them.

Why: ``bimcap refine`` fits the scans of the *as-built* to the *design*, so whatever part of the
walls' shifts a rigid move of the building explains goes into the poses (docs/deviations.md);
from the scans alone that common-mode displacement cannot be told from a pose error. A datum
fixes it: elements the user declares as built right (surveyed, or checked on site).

Selectors (:class:`DatumSpec`, from ``--datum`` or the ``datum`` key of a refine TOML), each one
string:

* ``guid:GLOBALID`` or a bare 22-character IFC GlobalId: that element;
* ``name:PATTERN``: every element whose ``Name`` matches the shell pattern (``fnmatch``,
  case-sensitive), e.g. ``name:*ext-*``;
* ``class:IfcColumn``: every element of that IFC class (case-insensitive).

Only walls, columns, floor slabs and ceiling coverings (the analysed elements) can be a datum.

The correction (:func:`fit_datum`) is one rigid motion of the world, ``p' = R_z(yaw) (p − c) + c
+ (dx, dy, dz)`` about the centre ``c`` of the datum's hits, applied to every return and sensor
centre (equivalently ``world_from_cam' = T · world_from_cam`` for every frame): it is fitted by
trimmed least squares so that the datum elements' returns lie on their design faces (each return
``e`` metres in front of its face along the face normal ``m`` moves by ``m · Δp``), re-cast and
refitted until it changes by less than 0.1 mm (the first cast takes every ray, the later ones
only those that met the datum). Walls give x, y and, with lever arm along their
length, yaw; columns x and y; floor slabs and ceilings z. Degrees of freedom the datum does not
constrain are left uncorrected: x, y or yaw free in the design geometry of the datum is an error
before any expensive work (:func:`check_datum`); z free (no slab or covering in the datum) keeps
the refined poses' z and is said so (``DatumFit.free``).
"""

from __future__ import annotations

import fnmatch
import logging
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.deviations.analysis import (
    ANALYSED_LABELS,
    DeviationInputError,
    DeviationOptions,
    _analysed,
    _cast,
    _robust_fit,
    _scene,
    _surface_samples,
)
from bimcap.deviations.refined_map import ScanSet

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)

#: The degrees of freedom of the correction, in the order of its parameter vector.
DOF = ("x", "y", "yaw", "z")
#: A direction of the (length-normalised) correction whose mean squared sensitivity is below
#: this is not constrained by the datum.
MIN_SENSITIVITY = 0.01
#: An IFC GlobalId: 22 characters of IFC's base-64 alphabet.
_GUID = re.compile(r"^[0-9A-Za-z_$]{22}$")
#: The selector prefixes.
PREFIXES = ("guid", "name", "class")



class DatumError(DeviationInputError):
    """A datum that cannot be used: bad selector syntax, an unknown GUID, a selector matching no
    element, an element that cannot be a datum, or a datum that leaves x, y or yaw free."""


class DatumFitMode(str, Enum):
    """How the poses are corrected to the datum."""

    RIGID = "rigid"  #: one rigid motion of the whole trajectory (x, y, yaw, z)
    FRAMES = "frames"  #: the rigid motion, then one small motion per frame, jointly with an
    #: offset per non-datum element (free) and the datum's offsets held at zero


@dataclass(frozen=True)
class DatumSpec:
    """Elements declared as built right (see the module doc for the selectors).

    Attributes
    ----------
    selectors: the selector strings, as given.
    source: where they came from, for messages (``"--datum"``, ``"datum"`` of a TOML file).
    fit: how the poses are corrected to it (:class:`DatumFitMode`).
    """

    selectors: tuple[str, ...]
    source: str = "--datum"
    fit: DatumFitMode = DatumFitMode.FRAMES

    @classmethod
    def parse(cls, values: Iterable[str], source: str = "--datum",
              fit: DatumFitMode | str = DatumFitMode.FRAMES) -> DatumSpec | None:
        """A spec from selector strings (each may hold several, comma-separated); None when
        there are none. Raises :class:`DatumError` on a malformed selector."""
        out: list[str] = []
        for value in values:
            if not isinstance(value, str):
                raise DatumError(f"a selector must be a string, got {value!r}", field=source)
            for part in value.split(","):
                sel = part.strip()
                if not sel:
                    continue
                prefix, colon, rest = sel.partition(":")
                if colon:
                    if prefix.lower() not in PREFIXES:
                        raise DatumError(f"unknown selector {sel!r}: use guid:GLOBALID, "
                                         "name:PATTERN or class:IfcClass", field=source)
                    if not rest.strip():
                        raise DatumError(f"empty selector {sel!r}", field=source)
                elif not _GUID.match(sel):
                    raise DatumError(f"{sel!r} is not an IFC GlobalId (22 characters); for a "
                                     "name or a class use name:PATTERN or class:IfcClass",
                                     field=source)
                out.append(sel)
        try:
            mode = DatumFitMode(fit)
        except ValueError:
            raise DatumError(f"unknown datum fit {fit!r}; known: "
                             f"{[m.value for m in DatumFitMode]}", field="datum_fit") from None
        return cls(tuple(out), source, mode) if out else None

    def resolve(self, model: Any) -> list[int]:
        """Indices into ``model.elements`` of the datum (model order). Raises
        :class:`DatumError` naming the source and the selector for an unknown GUID, a selector
        that matches no element, or one that matches an element that cannot be a datum."""
        chosen: set[int] = set()
        for sel in self.selectors:
            prefix, colon, rest = sel.partition(":")
            kind = prefix.lower() if colon else "guid"
            arg = rest.strip() if colon else sel
            if kind == "guid":
                hits = [i for i, e in enumerate(model.elements) if e.guid == arg]
                if not hits:
                    raise DatumError(f"unknown IFC GUID {arg!r}: no element of the model has it",
                                     field=self.source)
            elif kind == "name":
                hits = [i for i, e in enumerate(model.elements)
                        if fnmatch.fnmatchcase(e.name or "", arg)]
                if not hits:
                    raise DatumError(f"{sel!r} matches no element's Name", field=self.source)
            else:
                hits = [i for i, e in enumerate(model.elements) if e.ifc_class.lower()
                        == arg.lower()]
                if not hits:
                    raise DatumError(f"{sel!r}: the model has no {arg}", field=self.source)
            usable = [i for i in hits if model.elements[i].label in ANALYSED_LABELS]
            if not usable:
                e = model.elements[hits[0]]
                raise DatumError(f"{sel!r} selects {e.ifc_class} {e.name or e.guid!r}: only "
                                 "walls, columns, floor slabs and ceilings can be a datum",
                                 field=self.source)
            chosen.update(usable)
        return sorted(chosen)

    def to_dict(self) -> dict[str, Any]:
        return {"selectors": list(self.selectors), "source": self.source,
                "fit": self.fit.value}

    def apply(self, model: Any, scans: ScanSet, map_points: F64 | None, opts: Any, scene: Any,
              gid_to_element: dict[int, int], ifc_path: Any
              ) -> tuple[ScanSet, F64 | None, dict[str, Any], set[int]]:
        """The datum step of :func:`bimcap.deviations.analysis.analyse_deviations`: resolve and
        check the datum, fit the correction (:func:`fit_datum`, then :func:`fit_frames` in the
        per-frame mode) and move the scans (and ``map_points``; None after a per-frame fit,
        which the merged map cannot follow). Returns the moved scans and map, the record of the
        fit (``report.datum``) and the datum's element indices (model order)."""
        indices = self.resolve(model)
        check_datum(model, indices, self.source, ifc_path)
        fit = fit_datum(model, scans, indices, self, opts, scene=scene,
                        gid_to_element=gid_to_element)
        info = fit.to_dict()
        if self.fit is DatumFitMode.FRAMES:
            frames = fit_frames(model, scans, indices, fit, opts, scene=scene,
                                gid_to_element=gid_to_element)
            info["frames"] = frames.to_dict()
            return frames.apply(scans), None, info, set(indices)
        moved_map = None if map_points is None else fit.apply_points(map_points)
        return fit.apply(scans), moved_map, info, set(indices)


def _jacobian(points: F64, normals: F64, centre: F64, scale: float) -> F64:
    """(M, 4) change of ``e`` (a return's distance in front of its face along the face normal
    ``m``, metres) per unit of (dx, dy, yaw × ``scale``, dz): ``m · Δp`` with ``Δp = (dx, dy, dz)
    + yaw ẑ × (p − c)``; yaw is scaled by ``scale`` (m) to compare with the translations."""
    d = points - centre
    yaw = (normals[:, 1] * d[:, 0] - normals[:, 0] * d[:, 1]) / scale
    return np.column_stack([normals[:, 0], normals[:, 1], yaw, normals[:, 2]])


def _describe(vec: F64) -> str:
    """A free direction (4,) of the correction in words."""
    v = vec / np.linalg.norm(vec)
    if abs(v[3]) > 0.9:
        return "z"
    if abs(v[2]) > 0.7:
        return "yaw"
    if abs(v[0]) > 0.95:
        return "x"
    if abs(v[1]) > 0.95:
        return "y"
    xy = v[:2] / max(np.linalg.norm(v[:2]), 1e-12)
    return f"translation along ({xy[0]:+.2f}, {xy[1]:+.2f})"


def _free_directions(jac: F64) -> tuple[F64, list[str]]:
    """The constrained directions (4, k) of a (M, 4) Jacobian and the free ones in words."""
    if len(jac) == 0:
        return np.zeros((4, 0)), list(DOF)
    info = jac.T @ jac / len(jac)
    vals, vecs = np.linalg.eigh(info)
    ok = vals > MIN_SENSITIVITY
    return vecs[:, ok], [_describe(vecs[:, k]) for k in np.flatnonzero(~ok)]


def _scale(points: F64) -> tuple[F64, float]:
    """Centre (3,) of ``points`` and their RMS horizontal distance from it (m, at least 1)."""
    c = points.mean(axis=0)
    r = float(np.sqrt(np.mean(np.sum((points[:, :2] - c[:2]) ** 2, axis=1))))
    return c, max(r, 1.0)


def check_datum(model: Any, indices: Sequence[int], source: str = "--datum",
                ifc_path: Any = None) -> list[str]:
    """Which degrees of freedom the datum's design geometry leaves free (from samples of the
    faces the analysis measures: wall and column sides, slab tops, ceiling undersides).

    Raises :class:`DatumError` when x, y or yaw is free (naming it and the datum); returns the
    free ones otherwise (``["z"]`` without a slab or covering, else ``[]``)."""
    wanted = set(indices)
    els = [el for el in _analysed(model, ifc_path, None) if el.index in wanted]
    rng = np.random.default_rng(0)
    samples = [_surface_samples(el, 0.1, rng) for el in els]
    samples = [s for s in samples if len(s)]
    if not samples:
        raise DatumError("the datum has no measurable face", field=source)
    s = np.concatenate(samples)
    centre, scale = _scale(s[:, :3])
    _, free = _free_directions(_jacobian(s[:, :3], s[:, 3:], centre, scale))
    names = ", ".join(sorted({model.elements[i].name or model.elements[i].guid
                              for i in indices})[:6])
    horizontal = [f for f in free if f != "z"]
    if horizontal:
        raise DatumError(f"the datum ({len(indices)} element(s): {names}) leaves "
                         f"{' and '.join(horizontal)} free: add an element of another "
                         "orientation (walls along x and along y, or two columns)", field=source)
    return free


@dataclass
class DatumFit:
    """The rigid correction that puts the datum where the design has it.

    Attributes
    ----------
    guids, names: the datum's elements.
    world_datum_from_world: (4, 4) the correction (metres), applied to every return, sensor
        centre and pose: ``world_from_cam' = world_datum_from_world · world_from_cam``.
    translation_m: (3,) its (dx, dy, dz) at ``centre_m``; yaw_deg: its rotation about z.
    centre_m: (3,) centre of the datum's hits (the rotation's pivot).
    free: degrees of freedom the observed datum did not constrain (left uncorrected).
    n_hits: datum returns used in the last fit; residual_rms_m: their RMS distance from the
        design faces after the correction (trimmed); iterations: fits made.
    source: the spec (:meth:`DatumSpec.to_dict`).
    """

    guids: list[str]
    names: list[str]
    world_datum_from_world: F64
    translation_m: tuple[float, float, float]
    yaw_deg: float
    centre_m: tuple[float, float, float]
    free: list[str]
    n_hits: int
    residual_rms_m: float
    iterations: int
    source: dict[str, Any]

    def apply_points(self, points: F64) -> F64:
        """(P, 3) world points → the datum's world."""
        t = self.world_datum_from_world
        out: F64 = np.asarray(points, dtype=np.float64) @ t[:3, :3].T + t[:3, 3]
        return out

    def apply(self, scans: ScanSet) -> ScanSet:
        """The scans (returns and sensor centres) in the datum's world."""
        return ScanSet(self.apply_points(scans.p_in_world), scans.frame,
                       self.apply_points(scans.origins))

    def apply_poses(self, world_from_cam: F64) -> F64:
        """(N, 7) TUM-order poses → the datum's world."""
        from bimcap.geometry.poses import compose, matrix_to_pose

        t = matrix_to_pose(self.world_datum_from_world[None])[0]
        out: F64 = compose(np.repeat(t[None], len(world_from_cam), axis=0),
                           np.asarray(world_from_cam, dtype=np.float64))
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"mode": "datum", "source": self.source, "guids": self.guids,
                "names": self.names,
                "world_datum_from_world": self.world_datum_from_world.tolist(),
                "translation_m": list(self.translation_m), "yaw_deg": self.yaw_deg,
                "centre_m": list(self.centre_m), "free": self.free, "n_hits": self.n_hits,
                "residual_rms_m": self.residual_rms_m, "iterations": self.iterations}


def _rigid(dx: float, dy: float, dz: float, yaw: float, centre: F64) -> F64:
    """(4, 4) ``p ↦ R_z(yaw) (p − c) + c + (dx, dy, dz)``."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = centre - rot @ centre + np.array([dx, dy, dz])
    return out


def fit_datum(model: Any, scans: ScanSet, indices: Sequence[int], spec: DatumSpec,
              options: DeviationOptions | None = None, max_iterations: int = 6,
              scene: Any = None, gid_to_element: dict[int, int] | None = None) -> DatumFit:
    """The rigid correction of ``scans`` (see the module doc) that puts the returns on the datum
    elements ``indices`` (into ``model.elements``) onto their design faces.

    Raises :class:`DatumError` when no return hits the datum (nothing to fit)."""
    opts = options or DeviationOptions()
    if scene is None or gid_to_element is None:
        scene, gid_to_element = _scene(model, opts)
    wanted = np.zeros(len(model.elements), dtype=bool)
    wanted[list(indices)] = True
    max_gid = max(gid_to_element, default=-1)
    gid_datum = np.zeros(max_gid + 2, dtype=bool)
    for g, m_idx in gid_to_element.items():
        gid_datum[g] = wanted[m_idx]
    total = np.eye(4)
    rays = scans.subsample(opts.ray_step)
    cos_min = np.cos(np.radians(opts.max_incidence_deg))
    free: list[str] = list(DOF)
    n_hits, rms, it = 0, float("nan"), 0
    centre = np.zeros(3)
    scale = 1.0
    for it in range(1, max_iterations + 1):
        moved = ScanSet(rays.p_in_world @ total[:3, :3].T + total[:3, 3], rays.frame,
                        rays.origins @ total[:3, :3].T + total[:3, 3])
        hits = _cast(scene, moved)
        gid = hits["gid"]
        if it == 1:  # later fits re-cast only the rays that met the datum (a few cm move)
            met = (gid >= 0) & gid_datum[np.clip(gid, 0, max_gid + 1)]
            rays = ScanSet(rays.p_in_world[met], rays.frame[met], rays.origins)
            hits = {k: (v[met] if isinstance(v, np.ndarray) and len(v) == len(met) else v)
                    for k, v in hits.items()}
            gid = hits["gid"]
        on = (gid >= 0) & gid_datum[np.clip(gid, 0, max_gid + 1)] & (hits["cos"] >= cos_min)
        e = (np.where(on, hits["t"], 0.0) - hits["r"]) * hits["cos"]
        on &= np.abs(e) <= opts.pass_margin_m
        n_hits = int(on.sum())
        if n_hits < opts.min_points:
            raise DatumError(f"only {n_hits} returns hit the datum (at least {opts.min_points} "
                             "needed): the walk does not see it", field=spec.source)
        pts, m, e_on = hits["h"][on], hits["m"][on], e[on]
        if it == 1:
            centre, scale = _scale(pts)
        jac = _jacobian(pts, m, centre, scale)
        basis, free = _free_directions(jac)
        if basis.shape[1] == 0:
            break
        coef, keep = _robust_fit(jac @ basis, -e_on, opts.trim_mad)
        step = basis @ coef
        rms = float(np.sqrt(np.mean((e_on + jac @ step)[keep] ** 2)))
        step_t = _rigid(step[0], step[1], step[3], step[2] / scale, centre)
        total = step_t @ total
        if np.linalg.norm(step[[0, 1, 3]]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    if free:
        log.warning("the observed datum does not constrain %s: left uncorrected",
                    ", ".join(free))
    yaw = float(np.arctan2(total[1, 0], total[0, 0]))
    rot = total[:3, :3]
    t_at_c = total[:3, 3] + rot @ centre - centre
    return DatumFit(
        [model.elements[i].guid for i in indices], [model.elements[i].name for i in indices],
        total, (float(t_at_c[0]), float(t_at_c[1]), float(t_at_c[2])), float(np.degrees(yaw)),
        (float(centre[0]), float(centre[1]), float(centre[2])), free, n_hits, rms, it,
        spec.to_dict())


#: Prior scales of the joint fit's per-frame steps (beyond the rigid correction): the change of
#: the step from one frame to the next, translation (m) and yaw (degrees) — a refinement's pose
#: error drifts smoothly along the walk — and, much weaker, the step itself (m; the yaw's at
#: 1 m), which only fixes what nothing else does.
FRAME_SMOOTH_M = 0.01
FRAME_SMOOTH_YAW_DEG = 0.1
FRAME_PRIOR_M = 0.1
#: Each frame's returns count as this many independent observations in the joint fit (their
#: errors are not independent: one pose, a few elements), at the LiDAR's noise
#: (:data:`_NOISE_M`): a frame's well-seen directions follow its returns, while one that only
#: the frame's own free elements see (a room whose partitions no other frame sees) stays near
#: the prior instead of drifting with them.
FRAME_EFFECTIVE_ROWS = 200
_NOISE_M = 0.03


@dataclass
class FrameCorrections:
    """Per-frame corrections of the joint fit (after the rigid one).

    Attributes
    ----------
    world_datum_from_world: (N, 4, 4) per frame: ``world_from_cam' = T_f · world_from_cam``
        (the rigid correction included).
    step: (N, 4) each frame's own (dx, dy, dz in metres, yaw in degrees) beyond the rigid one,
        about its sensor centre.
    n_rows: returns used; n_elements: non-datum elements whose offset was estimated with them;
        iterations: solves made; residual_rms_m: RMS of the kept residuals (m).
    """

    world_datum_from_world: F64
    step: F64
    n_rows: int
    n_elements: int
    iterations: int
    residual_rms_m: float

    def apply(self, scans: ScanSet) -> ScanSet:
        t = self.world_datum_from_world
        rot, trans = t[:, :3, :3], t[:, :3, 3]
        f = scans.frame
        p = np.einsum("rij,rj->ri", rot[f], scans.p_in_world) + trans[f]
        o = np.einsum("nij,nj->ni", rot, scans.origins) + trans
        return ScanSet(p, f, o)

    def apply_poses(self, world_from_cam: F64) -> F64:
        """(N, 7) TUM-order poses → the datum's world, frame by frame."""
        from bimcap.geometry.poses import compose, matrix_to_pose

        out: F64 = compose(matrix_to_pose(self.world_datum_from_world),
                           np.asarray(world_from_cam, dtype=np.float64))
        return out

    def to_dict(self) -> dict[str, Any]:
        """Summary, each frame's own step ``frames`` ([dx, dy, dz, yaw_deg]) and its whole
        correction ``world_datum_from_world`` (TUM order [tx, ty, tz, qx, qy, qz, qw])."""
        from bimcap.geometry.poses import matrix_to_pose

        trans = np.linalg.norm(self.step[:, :3], axis=1)
        return {"n_rows": self.n_rows, "n_elements": self.n_elements,
                "iterations": self.iterations, "residual_rms_m": self.residual_rms_m,
                "frame_step_rms_m": float(np.sqrt(np.mean(trans**2))) if len(trans) else 0.0,
                "frame_step_max_m": float(trans.max()) if len(trans) else 0.0,
                "frame_yaw_max_deg": float(np.abs(self.step[:, 3]).max()) if len(trans)
                else 0.0,
                "frames": [[round(float(v), 6) for v in row] for row in self.step],
                "world_datum_from_world": matrix_to_pose(self.world_datum_from_world).tolist()}


def fit_frames(model: Any, scans: ScanSet, indices: Sequence[int], rigid: DatumFit,
               options: DeviationOptions | None = None, max_iterations: int = 4,
               scene: Any = None, gid_to_element: dict[int, int] | None = None
               ) -> FrameCorrections:
    """The joint fit of :attr:`DatumFitMode.FRAMES`: from the rigidly corrected ``scans`` (not
    yet moved: the rigid fit ``rigid`` is applied here), per frame ``f`` a small motion
    ``ξ_f = (dx, dy, yaw, dz)`` about its sensor centre and per non-datum element its offset
    ``δ_k`` (along the wall normal / a column's (dx, dy) / z), the datum's held at zero, by
    trimmed linear least squares over every hitting return: ``e_i + J_i ξ_f − b_i · δ_k ≈ 0``
    (``b_i`` the element's offset axes against the face normal, as in the analysis), each
    frame's returns weighed as :data:`FRAME_EFFECTIVE_ROWS` observations at 3 cm, with a prior
    on the steps (beyond the rigid correction): consecutive frames alike
    (:data:`FRAME_SMOOTH_M`, :data:`FRAME_SMOOTH_YAW_DEG`), each small (:data:`FRAME_PRIOR_M`);
    re-cast and refitted until the frames move by less than
    0.2 mm (every ``4 × ray_step``-th return is used). An element seen by several frames ties
    them together: a frame is placed by the datum it sees and by the elements it shares with
    frames that see the datum.
    """
    from scipy import sparse

    opts = options or DeviationOptions()
    if scene is None or gid_to_element is None:
        scene, gid_to_element = _scene(model, opts)
    elements = _analysed(model, None, None)
    datum = set(indices)
    n_frames = len(scans.origins)
    # columns of the unknowns: 4 per frame, then each non-datum element's offset axes
    col0 = np.full(len(model.elements), -1, np.int64)
    kind = np.full(len(model.elements), -1, np.int64)  # 0 wall, 1 column, 2 plate
    axes: dict[int, F64] = {}
    ncol = 4 * n_frames
    for el in elements:
        kind[el.index] = {"wall": 0, "column": 1}.get(el.kind, 2)
        axes[el.index] = el.axes
        if el.index not in datum:
            col0[el.index] = ncol
            ncol += len(el.axes)
    max_gid = max(gid_to_element, default=-1)
    gid_model = np.full(max_gid + 2, -1, np.int64)
    for g, m_idx in gid_to_element.items():
        gid_model[g] = m_idx
    cos_min = np.cos(np.radians(opts.max_incidence_deg))
    per_frame = np.repeat(rigid.world_datum_from_world[None], n_frames, axis=0)
    steps = np.zeros((n_frames, 4))
    rays = scans.subsample(4 * opts.ray_step)
    rows_used, n_el, rms, solves = 0, 0, float("nan"), 0
    # prior (rows of unit noise) on (dx, dy, yaw at 1 m, dz): consecutive frames' steps alike,
    # every step small; as a (4N, 4N) information matrix
    w_smooth = np.array([1.0, 1.0, 0.0, 1.0]) / FRAME_SMOOTH_M
    w_smooth[2] = 1.0 / np.radians(FRAME_SMOOTH_YAW_DEG)
    diff = np.zeros((max(n_frames - 1, 0), n_frames))
    diff[np.arange(n_frames - 1), np.arange(n_frames - 1)] = -1.0
    diff[np.arange(n_frames - 1), np.arange(1, n_frames)] = 1.0
    prior_info = np.kron(diff.T @ diff, np.diag(w_smooth**2))
    prior_info += np.eye(4 * n_frames) / FRAME_PRIOR_M**2
    total = np.zeros((n_frames, 4))  # each frame's step so far, (dx, dy, yaw, dz)
    for _ in range(max_iterations):
        solves += 1
        cur = FrameCorrections(per_frame, steps, 0, 0, 0, 0.0).apply(rays)
        hits = _cast(scene, cur)
        gid = hits["gid"]
        elem = np.where(gid >= 0, gid_model[np.clip(gid, 0, max_gid + 1)], -1)
        ok = (elem >= 0) & (hits["cos"] >= cos_min)
        ok &= kind[np.maximum(elem, 0)] >= 0
        e = (np.where(ok, hits["t"], 0.0) - hits["r"]) * hits["cos"]
        ok &= np.abs(e) <= opts.pass_margin_m
        m = hits["m"]
        k_of = kind[np.maximum(elem, 0)]
        # the faces that carry an offset (as the analysis uses them)
        wall_dot = np.zeros(len(e))
        for idx in np.unique(elem[ok & (k_of == 0)]):
            sel = ok & (elem == idx)
            wall_dot[sel] = m[sel] @ axes[int(idx)][0]
        useful = np.where(k_of == 0, np.abs(wall_dot) > 0.9,
                          np.where(k_of == 1, np.abs(m[:, 2]) < 0.3, np.abs(m[:, 2]) > 0.9))
        ok &= useful
        # elements with too few rows (or never seen) are left out
        counts = np.bincount(elem[ok], minlength=len(model.elements))
        ok &= counts[np.maximum(elem, 0)] >= opts.min_points
        rows = np.flatnonzero(ok)
        f = rays.frame[rows]
        centre = cur.origins[f]
        jac = _jacobian(hits["h"][rows], m[rows], centre, 1.0)  # (M, 4): dx, dy, yaw, dz
        r_idx = [np.repeat(np.arange(len(rows)), 4)]
        c_idx = [(4 * f[:, None] + np.arange(4)[None, :]).ravel()]
        vals = [jac.ravel()]
        el_rows = elem[rows]
        for idx in np.unique(el_rows):
            if col0[idx] < 0:
                continue
            sel = np.flatnonzero(el_rows == idx)
            b = m[rows[sel]] @ axes[int(idx)].T  # (S, k)
            k = b.shape[1]
            r_idx.append(np.repeat(sel, k))
            c_idx.append(col0[idx] + np.tile(np.arange(k), len(sel)))
            vals.append(-b.ravel())
        # rows of unit noise: each frame's returns worth FRAME_EFFECTIVE_ROWS observations
        n_f = np.bincount(f, minlength=n_frames)
        w_row = np.sqrt(FRAME_EFFECTIVE_ROWS / np.maximum(n_f[f], 1)) / _NOISE_M
        rhs = -e[rows]
        a = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(r_idx),
                                                      np.concatenate(c_idx))),
                              shape=(len(rows), ncol))
        keep = np.ones(len(rows), dtype=bool)
        x = np.zeros(ncol)
        prior_rhs = np.zeros(ncol)
        prior_rhs[:4 * n_frames] = -(prior_info @ total.ravel())  # on the whole step
        for _ in range(3):  # trimmed least squares
            aw = sparse.diags(w_row * keep) @ a
            normal = (aw.T @ aw).toarray()
            normal[:4 * n_frames, :4 * n_frames] += prior_info
            normal[np.diag_indices(ncol)] += 1e-9
            x = np.linalg.solve(normal, aw.T @ (w_row * keep * rhs) + prior_rhs)
            res = rhs - a @ x
            med = float(np.median(res[keep]))
            mad = 1.4826 * float(np.median(np.abs(res[keep] - med)))
            keep = np.abs(res - med) <= opts.trim_mad * max(mad, 1e-3)
        xi = x[:4 * n_frames].reshape(n_frames, 4)
        total += xi
        for fi in range(n_frames):
            step_t = _rigid(xi[fi, 0], xi[fi, 1], xi[fi, 3], xi[fi, 2], cur.origins[fi])
            per_frame[fi] = step_t @ per_frame[fi]
        steps += xi[:, [0, 1, 3, 2]] * np.array([1.0, 1.0, 1.0, np.degrees(1.0)])
        rows_used = int(keep.sum())
        n_el = int(sum(1 for idx in np.unique(el_rows) if col0[idx] >= 0))
        rms = float(np.sqrt(np.mean((rhs - a @ x)[keep] ** 2)))
        if np.abs(xi).max() < 2e-4:
            break
    return FrameCorrections(per_frame, steps, rows_used, n_el, solves, rms)
