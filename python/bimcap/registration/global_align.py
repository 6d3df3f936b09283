"""Global alignment: a trajectory in a SLAM system's own frame, placed in the BIM with no guess.

A SLAM system (LIO-SAM, FAST-LIO, ORB-SLAM, ARKit) writes ``slam_from_cam``: it starts at its
own origin with an arbitrary heading and height datum. This stage estimates the rigid transform
``world_from_slam`` so that the coarse stage (:mod:`.coarse`, reach about 2 m / 20°) and the
bundle adjustment can take over:

1. **gravity** from the floor: the floor points of every frame give a normal per frame; their
   median is the SLAM frame's "up". Tilts below ``gravity_min_tilt_deg`` are left alone (an
   IMU keeps gravity; averaging the per-frame tilt noise of a drifted trajectory would only add
   its mean).
2. **height**: the median height of the floor points is matched to each storey's floor (every
   storey of the plan is tried; its plan section is the one the coarse stage uses).
3. **x, y, yaw over the whole plan of every storey**: all wall and column points of the
   trajectory, seen as one rigid scan, are matched by the correlative search of the coarse
   stage (:func:`.correlative.score_volume`, the visibility-aware score maps of
   :class:`.plan_maps.PlanMaps`) over the full circle of yaws and every translation that puts
   the trajectory's centre inside the storey's box; the best distinct peaks are refined by
   point-to-segment ICP (:func:`.icp.icp_2d`).
4. **score**: each hypothesis' fine score of its points (0-1, frame by frame with a little
   slack) times the fraction of its camera positions that lie in free space (inside the
   building, not in a wall), times ``(1 - x) ** see_through_power`` where ``x`` is the share of
   points whose ray from the camera passes through a plan wall (negative evidence: an alias
   room of another width, a wall where the building has a door), times ``a **
   range_power`` where ``a`` is the share of points whose range agrees with the plan's along
   their ray (:func:`range_agreement`: neither through a wall nor short of one). The
   hypotheses are ranked; two are *distinct* when their camera positions differ by more than
   ``distinct_m`` on average, their yaws by more than ``distinct_deg`` or their floors by more
   than ``distinct_z_m``.
5. **ambiguity**: when the second-best distinct hypothesis scores at least ``ambiguity_ratio``
   of the best (a symmetric corridor, repeated rooms), or when another storey explains the
   placed scan exactly as the best one's does (:func:`twin_storeys`: a tower of identical
   floors, which the scores cannot separate and the SLAM frame's heights do not), or when the
   plan repeats what the best placement saw somewhere else and the real scan placed there
   scores at least ``ambiguity_ratio`` of the best, or fits there acceptably where the plan
   repeats almost exactly (:func:`_plan_alias`, :func:`_alias_ambiguous`: a point-symmetric
   duplex, where drift can rank the wrong unit first; there only the real ranges along the rays
   where the two plans differ can lift the flag, :func:`alias_range_vote`), the result is
   ambiguous:
   :func:`global_align` raises :class:`AmbiguousAlignmentError` (with the ranked hypotheses)
   unless ``accept_ambiguous`` is set. A best hypothesis that fits badly raises
   :class:`GlobalAlignmentError`, after steps 3-4 ran once more on the scan with each frame
   turned by the yaw error its own walls show (:class:`FrameYaw`, :func:`_frame_yaws`: the
   frames' independent yaw errors can blur the rigid scan so that the truth is no peak of the
   search). Never a confident wrong answer.

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order, metres; angles in degrees in
the options and results, radians inside.
"""

from __future__ import annotations

import heapq
import itertools
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from enum import Enum
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix, transform_points
from bimcap.labels import Label
from bimcap.registration._coarse_steps import _subsample, cell_support
from bimcap.registration.coarse import FloorPlan, SemanticSamples
from bimcap.registration.correlative import score_volume, top_hypotheses
from bimcap.registration.distance_field import DistanceField
from bimcap.registration.errors import (
    AmbiguousAlignmentError,
    GlobalAlignmentError,
    RegistrationInputError,
)
from bimcap.registration.icp import (
    Correction2D,
    icp_2d,
    icp_2d_many,
    point_segment_distance,
    rot2,
)
from bimcap.registration.plan_maps import PlanMaps
from bimcap.registration.window_polish import WindowPolish, polish_windows

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
_T = TypeVar("_T")

# The wall that a placement's seen-through rays cross (:class:`SeenThroughWall`).
#: The faces of one wall: plan segments parallel to the most-crossed one (within 5°) and at
#: most this far from it (metres; walls are 0.1-0.4 m thick).
MAX_WALL_THICKNESS_M = 0.6
#: ... and its pieces on the far side of a door: collinear segments within this gap (metres).
MAX_DOOR_GAP_M = 1.5
#: The wall must be crossed by at least this share of the seen-through points.
MIN_WALL_SHARE = 0.6
#: Seen-through points counted per segment to find the most-crossed one (every k-th of them).
MAX_COUNTED = 400


class SeeThroughMargin(str, Enum):
    """Where the margin of :func:`see_through_fraction` is measured.

    ``RAY_ENDS``: the first and last ``margin_m`` of every ray are left out (along the ray).
    ``WALL``: a crossing counts only when the camera and the point are both at least
    ``margin_m`` from the crossed segment (the point lies that far behind the wall): a ray
    that grazes a wall at a shallow angle crosses it far from its ends for a point drifted a
    few centimetres behind the wall's face, which says nothing about the placement (a drifted
    walk along the 4 m rooms of AC20-FZK-Haus: 22 % of its points counted at the right
    placement), while an alias room of another width or a wall where the building has a door
    puts them a room's difference behind it.
    """

    RAY_ENDS = "ray_ends"
    WALL = "wall"


class FrameYaw(str, Enum):
    """When each frame's points are turned by its yaw error as the scan's own walls tell it
    (:func:`_frame_yaws`).

    ``OFF``: never. ``ON_REFUSAL``: when the best placement of the scan as given would be
    refused for its fit (fine score, free space or see-through share), the whole search runs
    again on the turned scan and its placements are taken instead, unless the refusal is for
    the see-through alone and one plan wall explains it (``frame_yaw_wall_share``: a wall
    missing as built). ``ALWAYS``: the search always reads the turned scan.
    """

    OFF = "off"
    ON_REFUSAL = "on_refusal"
    ALWAYS = "always"


@dataclass(frozen=True)
class GlobalAlignOptions:
    """Settings of :func:`global_align` (lengths in metres, angles in degrees).

    Attributes
    ----------
    resolution_m, sigma_m: the correlative grid and the width of its score (coarser than the
        coarse stage's: the whole drifted trajectory is matched as one rigid scan).
    yaw_step_deg: yaw grid of the full-circle search.
    view_bins: ray-direction bins of the visibility test (:mod:`.plan_maps`).
    top_k: peaks of the correlative volume refined by ICP, per storey.
    max_points: random subsample of the wall/column points for scoring.
    icp_points: at most this many of them (every k-th) drive the ICP of each peak.
    icp_radius_start_m, icp_radius_end_m, icp_iterations, icp_huber_m: the ICP of each peak.
    fine_resolution_m, fine_sigma_m, inlier_m: the maps that score a hypothesis after ICP.
    wall_band_m: wall/column points within this height of the floor or ceiling are ignored.
    plan_cut_height_m: a storey's plan section holds the segments whose ``segment_z`` range
        holds ``floor + plan_cut_height_m`` (as in the coarse stage).
    rescore_top: the best distinct rigid fits of each storey that get the per-frame fit (8: with
        the support-weighted template the demo walk of `test_gravity_from_the_floor_levels_a_
        tilted_slam_frame` has four wrong places of a higher rigid fit than the right one).
    frame_yaw_deg, frame_yaw_step_deg, frame_shift_m: the per-frame slack of the ranking fit
        (:func:`_frame_fit`): each frame may turn and shift this much on its own.
    level_from_floor, gravity_min_tilt_deg: estimate gravity from the floor points; apply it
        only when the SLAM frame is tilted by more than this.
    frame_level_max_deg: each frame's wall and column points are turned about its camera so
        that the floor it sees is level (a drifted trajectory's per-frame tilt; the poses
        themselves are not changed), when that floor is tilted by at most this much (0: off).
    free_clearance_m: a camera closer than this to a wall is not in free space.
    enclosed_rays, enclosed_min_hits: a camera is inside the building when at least
        ``enclosed_min_hits`` of ``enclosed_rays`` horizontal rays hit the plan.
    see_through_margin_m, see_through_margin_from, see_through_power: negative evidence
        (:func:`see_through_fraction`): the share ``x`` of wall/column points whose ray from
        their camera passes through a plan wall (with a margin of ``see_through_margin_m`` for
        drift and noise at the camera and at the hit, measured as ``see_through_margin_from``
        says: :class:`SeeThroughMargin`) multiplies the ranking score by ``(1 - x) **
        see_through_power`` (0: not used).
    see_through_window_frames, see_through_window_yaw_deg, see_through_window_shift_m: a best
        placement that fits and would be refused for its see-through alone is measured again
        with each window of this many consecutive frames moved onto the plan by its own rigid
        ICP, taken only within this turn and shift (:func:`.window_polish.polish_windows`; 0
        frames: off), and so are the next ranked placements; it is taken when that share is at
        most ``max_see_through``, it stays the best with the shares so measured and the
        second-best scores at most ``see_through_window_max_ratio`` of it (a refusal is
        answered only where nothing else comes near: pipeline seed 8, 2 %; a demo walk with a
        0.7 m translation walk placed one bay off, 61 %), and no near-exact plan alias stands
        (:class:`DriftSeeThrough`). A drifted
        trajectory's translation walk is a small rigid offset per window, which one rigid
        placement cannot take out. The ranking itself does not use it: windows free to move
        erase the small differences between a point-symmetric plan's two placements (Duplex_A
        seed 16 ranked with it: placed 6.6 m off; docs/global_align.md, "The see-through under
        drift").
    range_tol_m, range_power: the range agreement of a placement (:func:`range_agreement`):
        the share ``a`` of wall/column points whose range from their camera agrees with the
        plan's, the first plan wall their ray crosses lying within ``range_tol_m`` of the point
        (neither seen through a wall nor short of one), multiplies the ranking score by
        ``a ** range_power`` (0: not used). It reads the free space along every ray, which the
        fit (the distance to the nearest wall, each frame free to shift) does not: an alias
        room of another width or depth leaves the scan's points short of its walls.
    template_support: a cell of the correlative search's occupancy template (half a
        ``resolution_m``, per class) counts fully when it holds at least this many of the
        scan's points, in proportion to them below (1: every occupied cell fully, a binary
        template); see :func:`_support_weight`.
    distinct_m, distinct_deg, distinct_z_m: two hypotheses are distinct when their camera
        positions differ by more than ``distinct_m`` on average, or their yaws by more than
        ``distinct_deg``, or their floors by more than ``distinct_z_m``.
    ambiguity_ratio: second-best / best score at or above which the result is ambiguous.
    min_score, min_free_fraction, max_see_through: the best hypothesis must have at least this
        fine score and this fraction of cameras in free space, and see at most this share of
        its points through plan walls, else :class:`GlobalAlignmentError` (a placement that
        puts walls where the sensor saw through is no fit, however the others score).
    alias_check, alias_points, alias_top, alias_tol_m, alias_rescore, alias_max_difference: the
        search for where else the plan repeats what the best placement saw
        (:func:`_plan_alias`): on/off, points of the ideal scan, peaks refined per storey, ICP
        tolerance, aliases rescored with the real scan, largest ideal difference rescored.
    alias_exact_difference: an alias where the plan repeats what the scan saw almost exactly
        (ideal difference at most this) makes the result ambiguous whatever the ratio of the
        real scores, when the real scan placed there would itself be accepted (``min_score``,
        ``min_free_fraction``, ``max_see_through``): the plan gives a perfect scan next to
        nothing to tell the two apart, so the real scan's gap is drift and noise
        (:func:`_alias_ambiguous`).
    alias_vote, alias_vote_differ_m, alias_vote_tol_m, alias_vote_min_votes,
        alias_vote_min_frames, alias_vote_min_share: the discriminating-ray vote at a
        near-exact alias (:func:`alias_range_vote`): the real scan's rays, as the best
        placement puts them, and their rigid image at the alias (where the plan repeats what
        the best placement saw); the rays whose first plan walls from the two lie more than
        ``alias_vote_differ_m`` (m) apart are the only ones that can tell the two apart, and
        each votes for the placement whose plan range its measured range meets within
        ``alias_vote_tol_m`` (m). With ``alias_vote`` on, a near-exact alias does not make the
        result ambiguous, whatever the ratio of the real scores (drift's, there), when at
        least ``alias_vote_min_votes`` rays from at least ``alias_vote_min_frames`` frames
        voted and the lower 95 % Wilson bound of the best placement's share of the votes is
        at least ``alias_vote_min_share`` (0-1); otherwise the near-exact rule stands. Aliases
        the plan tells apart (ideal difference above ``alias_exact_difference``) keep the
        ratio rule. (docs/global_align.md, "The discriminating-ray vote": the five near-exact
        flags of the generated worlds had 132-370 votes from 27-33 frames, 78-93 % for the best
        at the lower bound; every Duplex_A and AC20-FZK-Haus run at most 108 votes, and at most
        56 % at the bound with more than 20 votes.)
    frame_yaw, frame_yaw_max_deg, frame_yaw_cell_m, frame_yaw_neighbours, frame_yaw_radius_m:
        each frame's yaw error from the directions of its own walls against those of the whole
        scan (:class:`FrameYaw`, :func:`_frame_yaws`): when it is used, the largest turn of a
        frame (degrees), and the neighbourhood of a point whose principal direction is the
        wall's (the frame's points thinned to one per ``frame_yaw_cell_m`` cell; the point's
        ``frame_yaw_neighbours`` nearest, all within ``frame_yaw_radius_m``).
    frame_yaw_max_ratio: a placement found only on the turned scan after a refusal
        (``FrameYaw.ON_REFUSAL``) is taken only when the second-best scores at most this share
        of it, as the windowed see-through's ``see_through_window_max_ratio``: a second try
        must win by a wide margin (without it, a demo walk with its ends 0.5 m off, refused on
        the scan as given, was placed one bay along, 5 m off, at ratio 0.71;
        tests/test_registration_window_polish.py). Office_A seed 12, the run the turn places,
        has 0.06.
    frame_yaw_wall_share: ``FrameYaw.ON_REFUSAL`` does not search the turned scan when the
        best placement fits (fine score, free space) and is refused for its see-through alone,
        and at least this share of its seen-through rays cross one plan wall
        (:func:`dominant_seen_through_wall`, the rays polished as the
        see-through test reads them): a wall missing as built, which the frames' yaw errors do
        not explain and the missing-wall retry answers (the second search only doubled the
        time: pipeline seeds 3, 10 and 13 have 0.97, 0.87 and 0.71; Office_A seed 12, the
        run the turned scan places, 0.37). The default is the retry's own bar
        (:data:`MIN_WALL_SHARE`); above 1: the turned scan is always searched.
    fit_trim_frames, fit_trim_max_ratio: a best placement refused for its fit alone (below
        ``min_score``; free space, see-through and ambiguity passed) is measured again on the
        frames whose walls exist: the fit with the worst-fitting ``fit_trim_frames`` share of
        the frames set aside (a wall missing or shifted as built leaves a few frames with
        little to fit; 0: off), and taken when that fit is at least ``min_score`` and the
        second-best scores at most ``fit_trim_max_ratio`` of it (nothing else comes near, as
        for the other answers to a refusal). Pipeline seed 15 (as-built deviations; fit 0.64,
        0.62 at the true rigid placement): trimmed 0.67, ratio 0.07 (:class:`TrimmedFit`;
        docs/global_align.md, "32 pipeline seeds").
    accept_ambiguous: take the best hypothesis even when the result is ambiguous (flagged in
        the result, never hidden).
    report_top: hypotheses kept in the result.
    seed: seeds the random point subsampling.
    """

    resolution_m: float = 0.2
    sigma_m: float = 0.3
    yaw_step_deg: float = 2.0
    view_bins: int = 4
    top_k: int = 30
    max_points: int = 4000
    icp_points: int = 2000
    icp_radius_start_m: float = 0.8
    icp_radius_end_m: float = 0.12
    icp_iterations: int = 15
    icp_huber_m: float = 0.05
    fine_resolution_m: float = 0.05
    fine_sigma_m: float = 0.1
    inlier_m: float = 0.15
    wall_band_m: float = 0.3
    plan_cut_height_m: float = 1.0
    level_from_floor: bool = True
    gravity_min_tilt_deg: float = 2.0
    frame_level_max_deg: float = 30.0
    free_clearance_m: float = 0.15
    enclosed_rays: int = 16
    enclosed_min_hits: int = 10
    rescore_top: int = 8
    frame_yaw_deg: float = 12.0
    frame_yaw_step_deg: float = 2.0
    frame_shift_m: float = 0.2
    see_through_margin_m: float = 0.3
    see_through_margin_from: SeeThroughMargin = SeeThroughMargin.WALL
    see_through_power: float = 3.0
    see_through_window_frames: int = 10
    see_through_window_yaw_deg: float = 5.0
    see_through_window_shift_m: float = 0.5
    see_through_window_max_ratio: float = 0.2
    range_tol_m: float = 0.3
    range_power: float = 3.0
    distinct_m: float = 1.0
    distinct_deg: float = 10.0
    distinct_z_m: float = 0.5
    ambiguity_ratio: float = 0.9
    min_score: float = 0.65
    min_free_fraction: float = 0.5
    max_see_through: float = 0.15
    template_support: int = 10
    alias_check: bool = True
    alias_points: int = 1500
    alias_top: int = 10
    alias_tol_m: float = 0.1
    alias_rescore: int = 3
    alias_max_difference: float = 0.2
    alias_exact_difference: float = 0.1
    alias_vote: bool = True
    alias_vote_differ_m: float = 0.3
    alias_vote_tol_m: float = 0.3
    alias_vote_min_votes: int = 100
    alias_vote_min_frames: int = 10
    alias_vote_min_share: float = 0.7
    frame_yaw: FrameYaw = FrameYaw.ON_REFUSAL
    frame_yaw_max_deg: float = 15.0
    frame_yaw_cell_m: float = 0.1
    frame_yaw_neighbours: int = 10
    frame_yaw_radius_m: float = 1.0
    frame_yaw_max_ratio: float = 0.2
    frame_yaw_wall_share: float = MIN_WALL_SHARE
    fit_trim_frames: float = 0.1
    fit_trim_max_ratio: float = 0.2
    accept_ambiguous: bool = False
    report_top: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        for name, mode in (("see_through_margin_from", SeeThroughMargin),
                           ("frame_yaw", FrameYaw)):
            try:
                object.__setattr__(self, name, mode(getattr(self, name)))
            except ValueError:
                raise RegistrationInputError(
                    f"must be one of {[m.value for m in mode]}, got {getattr(self, name)!r}",
                    None, name) from None
        positive = ("resolution_m", "sigma_m", "yaw_step_deg", "icp_radius_start_m",
                    "icp_radius_end_m", "icp_huber_m", "fine_resolution_m", "fine_sigma_m",
                    "inlier_m", "frame_yaw_step_deg", "distinct_m", "distinct_deg", "distinct_z_m",
                    "alias_tol_m", "range_tol_m", "alias_vote_differ_m", "alias_vote_tol_m",
                    "frame_yaw_radius_m", "frame_yaw_cell_m")
        for name, value in asdict(self).items():
            if isinstance(value, float) and not np.isfinite(value):
                raise RegistrationInputError(f"must be finite, got {value}", None, name)
            if name in positive and not value > 0:
                raise RegistrationInputError(f"must be > 0, got {value}", None, name)
        for name in ("view_bins", "top_k", "max_points", "icp_points", "icp_iterations",
                     "enclosed_rays", "template_support",
                     "rescore_top", "report_top", "alias_points", "alias_top",
                     "frame_yaw_neighbours"):
            if getattr(self, name) < 1:
                raise RegistrationInputError(f"must be >= 1, got {getattr(self, name)}", None,
                                             name)
        for name in ("ambiguity_ratio", "min_score", "min_free_fraction", "max_see_through",
                     "alias_max_difference", "alias_exact_difference", "alias_vote_min_share",
                     "see_through_window_max_ratio", "frame_yaw_max_ratio", "fit_trim_frames",
                     "fit_trim_max_ratio"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise RegistrationInputError("must be in [0, 1]", None, name)
        if not 0 <= self.enclosed_min_hits <= self.enclosed_rays:
            raise RegistrationInputError("must be in [0, enclosed_rays]", None,
                                         "enclosed_min_hits")
        for name in ("wall_band_m", "gravity_min_tilt_deg", "frame_level_max_deg",
                     "free_clearance_m", "frame_yaw_deg",
                     "frame_shift_m", "see_through_margin_m", "see_through_power", "range_power",
                     "alias_vote_min_votes", "alias_vote_min_frames", "frame_yaw_max_deg",
                     "see_through_window_frames", "see_through_window_yaw_deg",
                     "see_through_window_shift_m", "frame_yaw_wall_share"):
            if getattr(self, name) < 0:
                raise RegistrationInputError("must be >= 0", None, name)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "see_through_margin_from": self.see_through_margin_from.value,
                "frame_yaw": self.frame_yaw.value}


@dataclass(frozen=True)
class AlignHypothesis:
    """One placement of the trajectory in the BIM.

    Attributes
    ----------
    world_from_slam: (7,) TUM-order transform from the SLAM frame to the BIM (world) frame.
    floor_z: the storey floor (world z, metres) the trajectory is put on (None: plan without
        floors; z unchanged).
    yaw_deg: the yaw of ``world_from_slam`` (degrees, (-180, 180]).
    score: ``fit_score × free_fraction × (1 - see_through) ** see_through_power ×
        range_agreement ** range_power``, the ranking score (0-1).
    fit_score: mean over frames of each frame's best fine score with a little per-frame slack
        (0-1, :func:`_frame_fit`).
    rigid_fit: mean fine score of all wall/column points, the trajectory taken as rigid.
    inlier_ratio: fraction of those within ``inlier_m`` of a same-class segment.
    free_fraction: fraction of the camera positions in free space.
    coarse_score: the correlative peak's score (0-1) before ICP.
    see_through: fraction of the wall/column points seen through a plan wall (0-1, negative
        evidence, :func:`see_through_fraction`).
    range_agreement: fraction of the wall/column points whose range agrees with the plan's
        (0-1, :func:`range_agreement`).
    constraint: how well the ICP inliers' wall directions hold the placement (0: free along
        one direction, 0.5: equally in every direction; :class:`.icp.IcpResult`).
    """

    world_from_slam: F64
    floor_z: float | None
    yaw_deg: float
    score: float
    fit_score: float
    rigid_fit: float
    inlier_ratio: float
    free_fraction: float
    coarse_score: float
    see_through: float = 0.0
    constraint: float = 0.0
    range_agreement: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["world_from_slam"] = [float(v) for v in self.world_from_slam]
        return d


@dataclass
class GlobalAlignResult:
    """Output of :func:`global_align`.

    Attributes
    ----------
    poses: (N, 7) ``world_from_cam`` of the best hypothesis (the coarse stage starts here).
    world_from_slam: (7,) the best hypothesis' transform.
    hypotheses: the best distinct hypotheses, best first (at most ``report_top``).
    ambiguous: the second-best scores at least ``ambiguity_ratio`` of the best, or the best
        placement's storey has an identical twin (``twin_floors``).
    ratio: second-best / best score (0 with a single hypothesis).
    twin_floors: floor heights (m) of the storeys that explain the placed scan exactly as the
        best placement's storey does (:func:`twin_storeys`): the storey is unknown whatever the
        scores say.
    alias: where else the plan repeats what the best placement saw, and the real scan's score
        there (:func:`_plan_alias`; None: nowhere, or ``alias_check`` off).
    accepted_ambiguous: ambiguous, and taken anyway (``accept_ambiguous``).
    frames_turned: the placements were searched on the scan with each frame turned by its yaw
        error as its walls tell it (:class:`FrameYaw`).
    seen_through_wall: the plan wall that most of the best placement's seen-through rays
        cross (:class:`SeenThroughWall`), when it was measured to decide whether
        to search the turned scan (``frame_yaw_wall_share``; the missing-wall retry reuses it);
        None: not measured, or nothing seen through.
    drift_see_through: the best placement's see-through measured again with each window of
        frames polished, when it was too high for the ranking's measure alone
        (:class:`DriftSeeThrough`; None: not needed, or ``see_through_window_frames`` 0).
    trimmed_fit: the best placement's fit measured again without its worst-fitting frames,
        when it was refused for its fit alone (:class:`TrimmedFit`; None: not needed, or
        ``fit_trim_frames`` 0).
    gravity_tilt_deg: the tilt of the SLAM frame estimated from the floor (degrees).
    gravity_applied: whether that tilt was taken out (above ``gravity_min_tilt_deg``).
    storeys: per storey tried, its floor z and the best score found there.
    timings: seconds per step and ``total``.
    options: the settings.
    """

    poses: F64
    world_from_slam: F64
    hypotheses: list[AlignHypothesis]
    ambiguous: bool
    ratio: float
    accepted_ambiguous: bool
    gravity_tilt_deg: float
    gravity_applied: bool
    storeys: list[dict[str, Any]]
    timings: dict[str, float]
    options: GlobalAlignOptions
    twin_floors: list[float] = field(default_factory=list)
    alias: PlanAlias | None = None
    frames_turned: bool = False
    drift_see_through: DriftSeeThrough | None = None
    seen_through_wall: SeenThroughWall | None = None
    trimmed_fit: TrimmedFit | None = None
    n_frames: int = field(init=False)

    def __post_init__(self) -> None:
        self.n_frames = len(self.poses)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``result.json`` → ``solve.global_align``)."""
        return {
            "n_frames": self.n_frames,
            "world_from_slam": [float(v) for v in self.world_from_slam],
            "hypotheses": [h.to_dict() for h in self.hypotheses],
            "ambiguous": self.ambiguous,
            "ratio": self.ratio,
            "twin_floors": list(self.twin_floors),
            "alias": None if self.alias is None else self.alias.to_dict(),
            "accepted_ambiguous": self.accepted_ambiguous,
            "frames_turned": self.frames_turned,
            "drift_see_through": (None if self.drift_see_through is None
                                  else self.drift_see_through.to_dict()),
            "seen_through_wall": (None if self.seen_through_wall is None
                                  else self.seen_through_wall.to_dict()),
            "trimmed_fit": None if self.trimmed_fit is None else self.trimmed_fit.to_dict(),
            "gravity_tilt_deg": self.gravity_tilt_deg,
            "gravity_applied": self.gravity_applied,
            "storeys": self.storeys,
            "timings": dict(self.timings),
            "options": self.options.to_dict(),
        }

    def describe(self) -> str:
        """One line per hypothesis: rank, score, yaw, translation, floor."""
        lines = []
        for k, h in enumerate(self.hypotheses, start=1):
            t = h.world_from_slam[:3]
            floor = "-" if h.floor_z is None else f"{h.floor_z:.2f} m"
            lines.append(f"  #{k}: score {h.score:.3f} (fit {h.fit_score:.3f}, free "
                         f"{h.free_fraction:.2f}, seen through walls {h.see_through:.2f}, range "
                         f"agreement {h.range_agreement:.2f}), yaw {h.yaw_deg:.1f} deg, t "
                         f"({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) m, floor "
                         f"{floor}")
        d = self.drift_see_through
        if d is not None:
            lines.append("  seen through walls with each window of frames polished (drift): "
                         + ", ".join(f"#{k}: {w:.2f}" for k, w in enumerate(d.windowed, 1))
                         + (" (accepted)" if d.accepted else " (not accepted)"))
        tf = self.trimmed_fit
        if tf is not None:
            lines.append(f"  fit without the worst {tf.frames_set_aside} of {tf.frames} frames: "
                         f"{tf.trimmed:.3f} (all frames, same points: {tf.fit:.3f})"
                         + (" (accepted)" if tf.accepted else " (not accepted)"))
        return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# Free space.


def free_space_fraction(cam_xy: NDArray[np.float64], segments: NDArray[np.float64],
                        field_: DistanceField | None = None, clearance_m: float = 0.15,
                        n_rays: int = 8, min_hits: int = 7, max_range_m: float = 60.0,
                        shell: NDArray[np.float64] | None = None
                        ) -> tuple[float, NDArray[np.bool_]]:
    """Fraction of camera positions in free space, and the per-camera flags.

    A position is free when at least ``min_hits`` of ``n_rays`` horizontal rays from it hit a
    segment of the shell within ``max_range_m`` (it is inside the building, not beside it) and
    it is at least ``clearance_m`` from every segment of the section (not inside a wall).

    Parameters
    ----------
    cam_xy: (N, 2) metres; segments: (S, 4) the storey's plan section.
    field_: a distance field of ``segments`` (built here when None).
    shell: (S', 4) the segments that enclose the storey (``_Storey``: under a pitched roof,
        also the storey below's walls); None: ``segments``.
    """
    cam = np.asarray(cam_xy, dtype=np.float64).reshape(-1, 2)
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    if len(cam) == 0:
        return 0.0, np.zeros(0, dtype=bool)
    if len(seg) == 0:
        return 0.0, np.zeros(len(cam), dtype=bool)
    if field_ is None:
        field_ = DistanceField.from_segments(seg, 0.1)
    clear = field_.lookup(cam) >= clearance_m
    if shell is not None:
        seg = np.asarray(shell, dtype=np.float64).reshape(-1, 4)
    a, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
    hits = np.zeros(len(cam), dtype=np.int64)
    # What does not depend on the ray's direction, once (the same arithmetic per ray).
    w = a[None] - cam[:, None]
    w0, w1 = w[..., 0], w[..., 1]
    s_num = w0 * e[None, :, 1] - w1 * e[None, :, 0]
    for k in range(n_rays):
        ang = 2 * np.pi * (k + 0.5) / n_rays
        d = np.array([np.cos(ang), np.sin(ang)])
        den = d[0] * e[:, 1] - d[1] * e[:, 0]
        ok = np.abs(den) > 1e-12
        if not ok.any():
            continue
        den_ok = den[ok][None]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = s_num[:, ok] / den_ok
            u = (w0[:, ok] * d[1] - w1[:, ok] * d[0]) / den_ok
        hit = (s > 0) & (s < max_range_m) & (u >= 0) & (u <= 1)
        hits += hit.any(1)
    free = clear & (hits >= min_hits)
    return float(free.mean()), free


def _ray_crossings(a_ray: F64, d_ray: F64, seg: F64, chunk: int
                   ) -> Iterator[tuple[int, F64, F64, F64, NDArray[np.bool_]]]:
    """The crossings of rays ``a + s d`` (s in [0, 1]; ``a_ray``, ``d_ray`` (N, 2) metres) with
    plan segments ``seg`` (S, 4), ``chunk`` rays at a time: per chunk, its first row ``k``, the
    segments' starts ``a`` (S', 2) and directions ``e`` (S', 2) that can be crossed, ``s``
    (chunk, S') the crossing's place along each ray and ``cross`` (chunk, S') whether the ray
    crosses the segment. Only the segments whose box meets the box of the chunk's rays are
    tested (the points come frame by frame, so a chunk's rays are local): the same test, fewer
    pairs."""
    seg_lo = np.minimum(seg[:, :2], seg[:, 2:])
    seg_hi = np.maximum(seg[:, :2], seg[:, 2:])
    for k in range(0, len(a_ray), chunk):
        o, d = a_ray[k:k + chunk, None], d_ray[k:k + chunk, None]
        ends = np.r_[a_ray[k:k + chunk], a_ray[k:k + chunk] + d_ray[k:k + chunk]]
        near = ((seg_lo <= ends.max(0) + 1e-6) & (seg_hi >= ends.min(0) - 1e-6)).all(1)
        a, e = seg[near, :2], seg[near, 2:] - seg[near, :2]
        den = d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]
        w = a[None] - o
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den  # along the ray
            t = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den  # along the segment
        yield k, a, e, s, (np.abs(den) > 1e-12) & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)


def _ray_crossings_near(a_ray: F64, d_ray: F64, seg: F64, chunk: int
                        ) -> Iterator[tuple[int, NDArray[np.int64], F64, F64, F64,
                                            NDArray[np.bool_]]]:
    """:func:`_ray_crossings` with the rows (S',) of ``seg`` that each chunk tests."""
    seg_lo = np.minimum(seg[:, :2], seg[:, 2:])
    seg_hi = np.maximum(seg[:, :2], seg[:, 2:])
    for k in range(0, len(a_ray), chunk):
        ends = np.r_[a_ray[k:k + chunk], a_ray[k:k + chunk] + d_ray[k:k + chunk]]
        near = np.flatnonzero(((seg_lo <= ends.max(0) + 1e-6)
                               & (seg_hi >= ends.min(0) - 1e-6)).all(1))
        for _, a, e, s, cross in _ray_crossings(a_ray[k:k + chunk], d_ray[k:k + chunk],
                                                seg[near], chunk):
            yield k, near, a, e, s, cross


def see_through_fraction(cam_xy: F64, p_xy: F64, segments: F64, margin_m: float = 0.3,
                         chunk: int = 256,
                         margin_from: SeeThroughMargin = SeeThroughMargin.RAY_ENDS
                         ) -> tuple[float, NDArray[np.bool_]]:
    """Negative evidence of a placement: the share of points seen *through* a wall of the plan.

    A camera sees a wall point along a straight ray; when that ray crosses a plan segment the
    placement puts a wall where the sensor saw free space (an alias room of another width, a
    wall where the true building has a door). ``margin_from`` ``RAY_ENDS``: the first and last
    ``margin_m`` of every ray are left out (the drift of the camera, noise and clutter at the
    hit); ``WALL``: a crossing counts only when the camera and the point are both at least
    ``margin_m`` from the crossed segment (:class:`SeeThroughMargin`). Either way rays shorter
    than ``2 margin_m`` never count.

    Parameters
    ----------
    cam_xy: (M, 2) the camera of each point, metres (world); p_xy: (M, 2) the points.
    segments: (S, 4) the storey's plan section.

    Returns
    -------
    The fraction (0-1) and the per-point flags (M,).
    """
    crossed, _ = see_through_counts(cam_xy, p_xy, segments, margin_m, chunk, margin_from)
    return (float(crossed.mean()) if len(crossed) else 0.0), crossed


def see_through_counts(cam_xy: F64, p_xy: F64, segments: F64, margin_m: float = 0.3,
                       chunk: int = 256,
                       margin_from: SeeThroughMargin = SeeThroughMargin.RAY_ENDS
                       ) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """:func:`see_through_fraction`'s per-point flags (M,), and per segment (S,) the number of
    points seen through it (a ray may cross several): ``counts[j]`` is the number of points
    that ``see_through_fraction`` flags with ``segments[j]`` alone, all counted in one pass."""
    cam = np.asarray(cam_xy, dtype=np.float64).reshape(-1, 2)
    pts = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    crossed = np.zeros(len(pts), dtype=bool)
    counts = np.zeros(len(seg), dtype=np.int64)
    if len(pts) == 0 or len(seg) == 0:
        return crossed, counts
    ray = pts - cam
    length = np.linalg.norm(ray, axis=1)
    use = length > 2 * margin_m
    from_wall = SeeThroughMargin(margin_from) == SeeThroughMargin.WALL
    if from_wall:  # whole rays; the margin is tested at the crossed segment
        a_ray, d_ray = cam[use], ray[use]
    else:
        u = ray[use] / length[use, None]
        a_ray = cam[use] + margin_m * u
        d_ray = ray[use] - 2 * margin_m * u
    hit = np.zeros(len(a_ray), dtype=bool)
    for k, near, a, e, _s, cross in _ray_crossings_near(a_ray, d_ray, seg, chunk):
        if from_wall and cross.any():
            # The margin at the crossed pairs only (few of the chunk's rays x segments).
            i, j = np.nonzero(cross)
            o, d = a_ray[k:k + chunk][i], d_ray[k:k + chunk][i]
            cross[i, j] = ((_point_segment_distance(o, a[j], e[j]) >= margin_m)
                           & (_point_segment_distance(o + d, a[j], e[j]) >= margin_m))
        hit[k:k + chunk] = cross.any(1)
        counts[near] += cross.sum(0)
    crossed[np.flatnonzero(use)] = hit
    return crossed, counts


def range_agreement(cam_xy: F64, p_xy: F64, segments: F64, tol_m: float = 0.3,
                    chunk: int = 256) -> tuple[float, NDArray[np.bool_]]:
    """The share of points whose range agrees with the plan: the ray from the camera through
    the point, extended ``tol_m`` beyond it, first crosses a plan segment within ``tol_m`` of
    the point (a beam model's test, in the plan).

    A point whose ray crosses a wall more than ``tol_m`` before it was seen through a wall
    (:func:`see_through_fraction`, without its margin); one whose ray meets no wall until
    ``tol_m`` beyond it lies in what the plan calls free space (clutter, furniture, or an alias
    room wider or deeper than the one the sensor saw). The nearest-wall fit misses the second
    kind whenever another wall is near, and its per-frame slack absorbs a few decimetres of
    width; along the ray, the plan's range is what it is.

    Parameters
    ----------
    cam_xy: (M, 2) the camera of each point, metres (world); p_xy: (M, 2) the points.
    segments: (S, 4) the storey's plan section.
    tol_m: the largest difference of range that agrees (metres, > 0).

    Returns
    -------
    The fraction (0-1) and the per-point flags (M,).
    """
    cam = np.asarray(cam_xy, dtype=np.float64).reshape(-1, 2)
    pts = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    # the ray extended tol_m beyond the point: its first wall, if any, must not lie short of it
    first = plan_ranges(cam, pts, segments, tol_m, chunk)
    agree = np.isfinite(first) & (first >= np.linalg.norm(pts - cam, axis=1) - tol_m)
    if len(pts) == 0:
        return 0.0, agree
    return float(agree.mean()), agree


def _point_segment_distance(p: F64, a: F64, e: F64) -> F64:
    """(M,) distance of each point ``p`` (M, 2) to its segment ``a + [0, 1] e`` (M, 2 each)."""
    w = p - a
    ee = np.maximum((e * e).sum(1), 1e-18)
    t = np.clip((w * e).sum(1) / ee, 0.0, 1.0)
    dist: F64 = np.linalg.norm(w - t[:, None] * e, axis=1)
    return dist


# ------------------------------------------------------------------------------------------------
# Steps.


@dataclass(frozen=True)
class _Storey:
    """One storey's plan section: its floor z (None: unknown), ceiling z, segment rows, and
    the rows of the shell that encloses it (``shell``; None: its own section).

    The shell is what the horizontal rays of the "inside the building" test may hit
    (:func:`free_space_fraction`, :func:`_free_map`). A storey with no ceiling above it (under
    a pitched roof: an attic) is enclosed by the roof, which the plan does not hold and which
    rests on the walls of the storey below; its own section can hold as little as the two gable
    walls (AC20-FZK-Haus), so its shell is its section and the section of the storey below."""

    floor_z: float | None
    ceiling_z: float | None
    rows: NDArray[np.int64]
    shell: NDArray[np.int64] | None = None

    @property
    def shell_rows(self) -> NDArray[np.int64]:
        """(S',) the segment rows of the storey's shell."""
        return self.rows if self.shell is None else self.shell


def _storeys(plan: FloorPlan, cut_m: float) -> list[_Storey]:
    """The distinct plan sections of ``plan``, one per storey, each with its main floor height
    (the floor nearest the bottom of the storey's wall band)."""
    n = len(plan.segments)
    if plan.segment_z is None or len(plan.floor_heights) == 0:
        fz = float(plan.floor_heights.min()) if len(plan.floor_heights) else None
        return [_Storey(fz, _ceiling_above(plan, fz), np.arange(n))]
    groups: dict[bytes, list[float]] = {}
    masks: dict[bytes, NDArray[np.bool_]] = {}
    for z in plan.floor_heights:
        zc = z + cut_m
        mask = (plan.segment_z[:, 0] <= zc) & (zc <= plan.segment_z[:, 1])
        if not mask.any():
            continue
        key = np.packbits(mask).tobytes()
        groups.setdefault(key, []).append(float(z))
        masks[key] = mask
    out = []
    for key, heights in groups.items():
        mask = masks[key]
        bottom = float(np.median(plan.segment_z[mask, 0]))
        fz = min(heights, key=lambda h: abs(h - bottom))
        out.append(_Storey(fz, _ceiling_above(plan, fz), np.flatnonzero(mask)))
    out.sort(key=lambda s: -np.inf if s.floor_z is None else s.floor_z)
    return _with_shells(out)


def _with_shells(out: list[_Storey]) -> list[_Storey]:
    """``out`` (sorted by floor) with the shell of each storey that has no ceiling above it
    and a storey below: its own rows and those of the storey below (see ``_Storey``)."""
    shelled = out[:1]
    for below, st in itertools.pairwise(out):
        if st.floor_z is not None and st.ceiling_z is None and below.floor_z is not None:
            st = replace(st, shell=np.union1d(st.rows, below.rows))
        shelled.append(st)
    return shelled


def _section_key(plan: FloorPlan, storey: _Storey) -> bytes:
    """Bytes equal for two storeys with the same plan section (segments, either end first,
    in any order, to 1 mm; classes) and the same floor-to-ceiling height (1 cm)."""
    seg = np.round(plan.segments[storey.rows] * 1000.0).astype(np.int64)
    flip = (seg[:, 0] > seg[:, 2]) | ((seg[:, 0] == seg[:, 2]) & (seg[:, 1] > seg[:, 3]))
    seg[flip] = seg[flip][:, [2, 3, 0, 1]]
    rows = np.c_[seg, plan.segment_class[storey.rows].astype(np.int64)]
    rows = rows[np.lexsort(rows.T[::-1])]
    height = (-1 if storey.floor_z is None or storey.ceiling_z is None
              else round(100.0 * (storey.ceiling_z - storey.floor_z)))
    shell = b"" if storey.shell is None else b"shell" + np.sort(storey.shell).tobytes()
    return rows.tobytes() + np.int64(height).tobytes() + shell


def _ceiling_above(plan: FloorPlan, z: float | None) -> float | None:
    if z is None or not len(plan.ceiling_heights):
        return None
    above = plan.ceiling_heights[plan.ceiling_heights > z]
    return float(above.min()) if len(above) else None


def twin_storeys(q_xy: F64, best: _Storey, storeys: list[_Storey], plan: FloorPlan,
                 near_m: float = 0.15, tol_m: float = 0.02, max_share: float = 0.01,
                 max_points: int = 5000) -> list[int]:
    """The other storeys that explain the placed scan exactly as ``best`` does: of the wall and
    column points ``q_xy`` (M, 2, the best placement) within ``near_m`` of ``best``'s plan
    section, at most ``max_share`` are nearer to or further from the other storey's section by
    more than ``tol_m``. A tower of identical floors (or floors identical wherever the walk
    looked) gives such twins; the SLAM frame's heights cannot tell them apart, so the storey is
    unknown whatever the scores say. Indices into ``storeys``."""
    q = np.asarray(q_xy, np.float64).reshape(-1, 2)
    if len(q) > max_points:
        q = q[np.linspace(0, len(q) - 1, max_points).astype(np.int64)]
    if not len(q) or not len(best.rows):
        return []
    reach = near_m + tol_m  # beyond it a distance only needs to be known to exceed it
    d_best = _distance_within(q, plan.segments[best.rows], reach)
    near = d_best <= near_m
    if not near.any():
        return []
    out = []
    for j, st in enumerate(storeys):
        if st is best or not len(st.rows):
            continue
        d = _distance_within(q[near], plan.segments[st.rows], reach)
        if float(np.mean(np.abs(d - d_best[near]) > tol_m)) <= max_share:
            out.append(j)
    return out


def _distance_within(p_xy: F64, segments: F64, reach_m: float, chunk: int = 256) -> F64:
    """(M,) distance of each point (M, 2) to its nearest segment (S, 4), exactly (as
    :func:`.icp.point_segment_distance`) where it is at most ``reach_m``; elsewhere some value
    above ``reach_m`` (``inf`` when no segment's box comes within ``reach_m`` of the chunk of
    points). Consecutive points (frame by frame) are taken ``chunk`` at a time against the
    segments near their box only."""
    out = np.full(len(p_xy), np.inf)
    lo = np.minimum(segments[:, :2], segments[:, 2:])
    hi = np.maximum(segments[:, :2], segments[:, 2:])
    for k in range(0, len(p_xy), chunk):
        q = p_xy[k:k + chunk]
        near = ((lo <= q.max(0) + reach_m) & (hi >= q.min(0) - reach_m)).all(1)
        if near.any():
            out[k:k + chunk] = point_segment_distance(q, segments[near])[0]
    return out


def _floor_normals(poses: F64, samples: SemanticSamples, min_points: int = 30
                   ) -> tuple[F64, NDArray[np.bool_]]:
    """(N, 3) each frame's floor normal in the frame of ``poses`` (pointing up: z >= 0), the
    plane fitted to its floor points; and (N,) whether the frame has at least ``min_points``
    of them (elsewhere the normal is +z)."""
    n_frames = len(poses)
    normals = np.tile([0.0, 0.0, 1.0], (n_frames, 1))
    has = np.zeros(n_frames, dtype=bool)
    fr, p = samples.floor_frame, samples.floor_p_in_cam
    if len(fr) < min_points:
        return normals, has
    pts = transform_points(poses[fr], p)
    order = np.argsort(fr, kind="stable")
    bounds = np.searchsorted(fr[order], np.arange(n_frames + 1))
    for i in range(n_frames):
        q = pts[order[bounds[i]:bounds[i + 1]]]
        if len(q) < min_points:
            continue
        c = q - q.mean(0)
        n = np.linalg.svd(c, full_matrices=False)[2][-1]
        normals[i], has[i] = (n if n[2] >= 0 else -n), True
    return normals, has


def _up_rotation(up: F64) -> F64:
    """(3, 3) the smallest rotation that turns the unit vector ``up`` (3,) onto +z."""
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    if s < 1e-12:
        return np.eye(3)
    angle = np.arctan2(s, up[2])
    rot: F64 = Rotation.from_rotvec(axis / s * angle).as_matrix()
    return rot


def _gravity(poses: F64, samples: SemanticSamples, min_points: int = 30) -> F64:
    """(3, 3) the rotation that turns the median per-frame floor normal (SLAM frame) onto +z."""
    normals, has = _floor_normals(poses, samples, min_points)
    if not has.any():
        return np.eye(3)
    up = np.median(normals[has], axis=0)
    up /= np.linalg.norm(up)
    return _up_rotation(up)


@dataclass(frozen=True)
class _Scan:
    """The trajectory's points in the levelled SLAM frame: wall/column xy (M, 2), their ray
    directions (M, 2), class (M,), height z (M,), frame (M,), camera positions (N, 3), the
    median floor height."""

    xy: F64
    view: F64
    cls: I32
    z: F64
    frame: I32
    cams: F64
    floor_z: float | None


def _frame_levels(poses: F64, samples: SemanticSamples, max_tilt_deg: float,
                  min_points: int = 30) -> F64:
    """(N, 3, 3) per frame, the rotation about its camera that turns its own floor normal
    (``poses``' frame, levelled) onto +z; the identity for a frame with fewer than
    ``min_points`` floor points or a floor tilted by more than ``max_tilt_deg`` (0: every
    frame the identity).

    A drifted trajectory's frames are tilted each by its own error (Exp 2: pitch noise of
    6.24 deg per frame; up to 15 deg in AC20-FZK-Haus seed 3's walk); projected onto the plan,
    a wall point 1 m above or below the camera then moves by up to 0.26 m. The floor each frame
    sees gives its own up (the poses are not changed: only the points the search and the
    scores read)."""
    levels = np.tile(np.eye(3), (len(poses), 1, 1))
    if max_tilt_deg <= 0:
        return levels
    normals, has = _floor_normals(poses, samples, min_points)
    for i in np.flatnonzero(has & (normals[:, 2] >= np.cos(np.deg2rad(max_tilt_deg)))):
        levels[i] = _up_rotation(normals[i] / np.linalg.norm(normals[i]))
    return levels


def _scan(poses: F64, samples: SemanticSamples, max_tilt_deg: float = 0.0) -> _Scan:
    """The wall/column points of ``samples`` under ``poses`` (N, 7, levelled frame), each
    frame's points turned about its camera by :func:`_frame_levels` (``max_tilt_deg`` 0: not
    turned)."""
    levels = _frame_levels(poses, samples, max_tilt_deg)
    xy, view, cls, zs, frames = [], [], [], [], []
    for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
        fr = getattr(samples, f"{c}_frame")
        if not len(fr):
            continue
        q = transform_points(poses[fr], getattr(samples, f"{c}_p_in_cam"))
        if max_tilt_deg > 0:
            cam = poses[fr, :3]
            q = np.einsum("mij,mj->mi", levels[fr], q - cam) + cam
        xy.append(q[:, :2])
        view.append(q[:, :2] - poses[fr, :2])
        cls.append(np.full(len(q), int(lab), np.int32))
        zs.append(q[:, 2])
        frames.append(fr)
    floor_z = None
    if len(samples.floor_frame):
        fq = transform_points(poses[samples.floor_frame], samples.floor_p_in_cam)
        floor_z = float(np.median(fq[:, 2]))
    if not xy:
        return _Scan(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int32), np.zeros(0),
                     np.zeros(0, np.int32), poses[:, :3].copy(), floor_z)
    return _Scan(np.concatenate(xy), np.concatenate(view), np.concatenate(cls),
                 np.concatenate(zs), np.concatenate(frames).astype(np.int32), poses[:, :3].copy(),
                 floor_z)


def _line_angles(p_xy: F64, cell_m: float, neighbours: int, radius_m: float,
                 max_points: int = 300) -> F64:
    """(K,) directions (degrees in [0, 180)) of the walls one frame's points (M, 2) lie on:
    the points thinned to one per ``cell_m`` cell (the first; a frame's density varies with
    the range), then at up to ``max_points`` of them (evenly spaced) the principal direction of
    the point's ``neighbours`` nearest thinned points when they all lie within ``radius_m`` and
    along a line (the larger spread at least 10 times the smaller, in variance)."""
    if len(p_xy) < 3:
        return np.zeros(0)
    _, first = np.unique(np.floor(p_xy / cell_m).astype(np.int64), axis=0, return_index=True)
    p_xy = p_xy[np.sort(first)]
    if len(p_xy) < 3:
        return np.zeros(0)
    q = p_xy[np.linspace(0, len(p_xy) - 1, min(len(p_xy), max_points)).astype(np.int64)]
    dist, nn = cKDTree(p_xy).query(q, k=min(neighbours, len(p_xy)))
    near = p_xy[nn]
    rel = near - near.mean(1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("mki,mkj->mij", rel, rel))
    line = (dist[:, -1] < radius_m) & (w[:, 1] > 10.0 * np.maximum(w[:, 0], 1e-12))
    ang: F64 = np.degrees(np.arctan2(v[line, 1, 1], v[line, 0, 1])) % 180.0
    return ang


def _frame_yaws(scan: _Scan, opt: GlobalAlignOptions, min_lines: int = 10,
                iterations: int = 3) -> F64:
    """(N,) each frame's yaw error (radians) as the scan's own walls tell it, no plan needed.

    The Exp 2 drift turns every frame by its own yaw error (independent per frame, 6-7 deg
    RMS, up to 17 deg on Office_A's walks), which blurs the whole trajectory taken as one rigid
    scan: Office_A seed 12's rigid fit at the truth is 0.42 (per frame 0.85), and no peak of the
    search lies near it; with the true per-frame yaw errors taken out it fits 0.73 rigidly and
    is placed right. A frame's walls (:func:`_line_angles`, a 1-degree histogram of their
    directions modulo 180 deg, smoothed) turned by its error are the scan's other walls turned
    by theirs; each frame's turn (whole degrees within ``frame_yaw_max_deg``) is the one that
    best correlates its histogram with the sum of the other frames' turned histograms, three
    rounds, the median turn of the frames with at least ``min_lines`` wall directions taken
    out each round (the whole scan's yaw is the search's). Frames with fewer are not turned."""
    n, bins = len(scan.cams), 180
    hist = np.zeros((n, bins))
    for i in range(n):
        ang = _line_angles(scan.xy[scan.frame == i], opt.frame_yaw_cell_m,
                           opt.frame_yaw_neighbours, opt.frame_yaw_radius_m)
        hist[i] = np.bincount(np.floor(ang).astype(np.int64) % bins, minlength=bins)
    has = hist.sum(1) >= min_lines
    turn = np.zeros(n, dtype=np.int64)
    if has.sum() < 2:
        return np.zeros(n)
    ker = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
    wrapped = np.concatenate([hist[:, -4:], hist, hist[:, :4]], axis=1)
    smooth = np.stack([np.convolve(h, ker, "valid") for h in wrapped])
    limit = int(np.floor(opt.frame_yaw_max_deg))
    shifts = np.arange(-limit, limit + 1)
    for _ in range(iterations):
        turned = np.stack([np.roll(smooth[i], -turn[i]) for i in range(n)])
        total = turned[has].sum(0)
        for j in np.flatnonzero(has):
            others = total - turned[j]
            scores = [float(np.dot(np.roll(smooth[j], -int(sh)), others)) for sh in shifts]
            turn[j] = int(shifts[int(np.argmax(scores))])
        turn[has] -= int(np.round(np.median(turn[has])))
        turn = np.clip(turn, -limit, limit)
    return np.deg2rad(turn.astype(np.float64))


def _turned(scan: _Scan, yaw: F64) -> _Scan:
    """``scan`` with each frame's points and rays turned about its camera by ``-yaw[frame]``
    (radians, (N,)): its yaw error taken out (the cameras and the poses do not change)."""
    c, s = np.cos(-yaw)[scan.frame], np.sin(-yaw)[scan.frame]
    rel = scan.xy - scan.cams[scan.frame, :2]
    xy = scan.cams[scan.frame, :2] + np.c_[c * rel[:, 0] - s * rel[:, 1],
                                           s * rel[:, 0] + c * rel[:, 1]]
    v = scan.view
    view = np.c_[c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]]
    return replace(scan, xy=xy, view=view)


@dataclass(frozen=True)
class _Found:
    """A hypothesis in the levelled SLAM frame: 2-D correction, storey, per-frame fit (the
    ranking fit), rigid fit, inlier ratio, free fraction, correlative score, cameras (N, 2),
    the share seen through walls and the range agreement, with their powers in the score."""

    corr: Correction2D
    storey: _Storey
    fit: float
    rigid_fit: float
    inliers: float
    free: float
    coarse: float
    cams_xy: F64
    see_through: float = 0.0
    see_through_power: float = 0.0
    constraint: float = 0.0
    agreement: float = 1.0
    agreement_power: float = 0.0

    @property
    def score(self) -> float:
        return self.score_without_range * float(self.agreement ** self.agreement_power)

    @property
    def score_without_range(self) -> float:
        """The score without its range agreement factor."""
        return float(self.fit * self.free * (1.0 - self.see_through) ** self.see_through_power)


@dataclass(frozen=True)
class _StoreyMaps:
    """One storey's search maps: its plan section (S, 4) and classes (S,), box bounds, centre
    (2,) and half-width (m), the layered score maps, a 0.1 m distance field, the coarse
    raster of where a camera may stand (:func:`_free_map`), the segments of the storey's
    shell (S', 4; None: its section; ``_Storey``) and the half-height of the box (m; None:
    ``half``). The search puts the trajectory's centre anywhere within ``half`` of ``centre``
    along x and ``half_y`` along y: the box and 1 m around it."""

    seg: F64
    seg_cls: I32
    bounds: tuple[float, float, float, float]
    centre: F64
    half: float
    maps: PlanMaps
    field_: DistanceField
    free_map: NDArray[np.float32]
    shell: F64 | None = None
    half_y: float | None = None
    # The cameras' free-space volumes already correlated (:func:`_free_volume`), by the
    # cameras and the grid: a second search of the same trajectory (its frames turned,
    # ``frame_yaw``) moves the points, not the cameras.
    free_volumes: dict[bytes, NDArray[np.float32]] = field(default_factory=dict, repr=False,
                                                           compare=False)


def _storey_maps(storey: _Storey, plan: FloorPlan, opt: GlobalAlignOptions) -> _StoreyMaps:
    seg = plan.segments[storey.rows]
    seg_cls = plan.segment_class[storey.rows]
    shell = None if storey.shell is None else plan.segments[storey.shell]
    # The box of the shell: a walk under a roof may reach beyond the gable walls' box.
    box_xy = (seg if shell is None else shell).reshape(-1, 2)
    lo, hi = box_xy.min(0), box_xy.max(0)
    bounds = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    maps = PlanMaps.build(seg, seg_cls, bounds, 3.0, opt.view_bins, opt.resolution_m,
                          opt.sigma_m, opt.fine_resolution_m, opt.fine_sigma_m, 3.0)
    # The search's translations cover the box and 1 m around it along each axis (not the
    # square of the longer side: Office_A's 50 x 36 m box: 26 % fewer translations).
    half = 0.5 * (hi - lo) + 1.0
    return _StoreyMaps(seg, seg_cls, bounds, 0.5 * (lo + hi), float(half[0]), maps,
                       DistanceField.from_segments(seg, 0.1, bounds, 3.0),
                       _free_map(seg, bounds, opt, shell), shell, float(half[1]))


def _maps_key(storey: _Storey, plan: FloorPlan, opt: GlobalAlignOptions) -> bytes:
    """Bytes equal for two storeys whose maps (:func:`_storey_maps`) are the same, bit for bit:
    the same section's segments (in the same order) and classes, the same shell's segments, the
    same options. Two plans may share it (the plan without one wall: every other storey)."""
    shell = (b"none" if storey.shell is None
             else b"shell" + np.ascontiguousarray(plan.segments[storey.shell]).tobytes())
    return (np.ascontiguousarray(plan.segments[storey.rows]).tobytes() + b"|"
            + np.ascontiguousarray(plan.segment_class[storey.rows]).tobytes() + b"|" + shell
            + b"|" + repr(opt).encode())


def _cached_storey_maps(storey: _Storey, plan: FloorPlan, opt: GlobalAlignOptions,
                        maps_cache: dict[bytes, Any] | None) -> _StoreyMaps:
    """:func:`_storey_maps`, kept in ``maps_cache`` (None: built, not kept) by
    :func:`_maps_key`."""
    if maps_cache is None:
        return _storey_maps(storey, plan, opt)
    key = _maps_key(storey, plan, opt)
    if key not in maps_cache:
        maps_cache[key] = _storey_maps(storey, plan, opt)
    return cast("_StoreyMaps", maps_cache[key])


def _keep(scan: _Scan, storey: _Storey, opt: GlobalAlignOptions) -> NDArray[np.bool_]:
    """(M,) the wall/column points of ``scan`` between the floor and ceiling bands of
    ``storey`` (its plan section holds walls only at those heights)."""
    keep = np.ones(len(scan.xy), dtype=bool)
    if scan.floor_z is not None and opt.wall_band_m > 0:
        keep &= scan.z > scan.floor_z + opt.wall_band_m
        if storey.floor_z is not None and storey.ceiling_z is not None:
            keep &= scan.z < scan.floor_z + (storey.ceiling_z - storey.floor_z) - opt.wall_band_m
    return keep


def _support_weight(xy: F64, cls: I32, occ: NDArray[np.int64], opt: GlobalAlignOptions
                    ) -> F64 | None:
    """(len(occ),) the weight of each template point ``xy[occ]`` (M, 2) in the correlative
    search: the points of its (0.5 ``resolution_m`` cell, class) over ``template_support``,
    at most 1 (None when ``template_support`` is 1: the binary template).

    One point per cell flattens the scan into its shape, but it also gives a stray return
    (noise, clutter, a range cut short) the weight of a wall seen by every frame: a short walk
    in small rooms sees the same few metres of wall over and over (Duplex_A: 94 % of the points
    but 23 % of the cells on walls at the truth, so its best search peak was never near it)."""
    if opt.template_support <= 1 or len(occ) == 0:
        return None
    support = cell_support(xy, cls, 0.5 * opt.resolution_m)[occ]
    return np.minimum(support / float(opt.template_support), 1.0)


def _search_storey(scan: _Scan, storey: _Storey, sm: _StoreyMaps, opt: GlobalAlignOptions,
                   rng: np.random.Generator, timings: dict[str, float]) -> list[_Found]:
    """Steps 3-4 on one storey: full-circle correlative search over the storey's box, ICP of
    the top peaks, fine score and free-space fraction of each."""
    seg, keep = sm.seg, _keep(scan, storey, opt)
    xy, view, cls, frame = scan.xy[keep], scan.view[keep], scan.cls[keep], scan.frame[keep]
    if len(xy) < 20 or len(seg) == 0:
        return []
    maps, field_, centre, half = sm.maps, sm.field_, sm.centre, sm.half
    # Shift the scan so that its camera centroid sits on the box centre: the translations of
    # the search then put the centroid anywhere in the box.
    shift = centre - scan.cams[:, :2].mean(0)
    xy_s, cams_s = xy + shift, scan.cams[:, :2] + shift
    t0 = time.perf_counter()
    occ = _subsample(xy_s, cls, 0.5 * opt.resolution_m, 40 * opt.max_points, rng)
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(opt.yaw_step_deg))
    weight = _support_weight(xy_s, cls, occ, opt)
    vol, res, n = score_volume(xy_s[occ], cls[occ], view[occ], maps, centre, yaws, half,
                               p_weight=weight, y_range_m=sm.half_y)
    # The trajectory's own shape: the share of its cameras in free space, for every (yaw, t).
    m = (vol.shape[1] - 1) // 2
    key = cams_s.tobytes() + yaws.tobytes() + np.array([res, n, m], np.float64).tobytes()
    if key not in sm.free_volumes:
        sm.free_volumes[key] = _free_volume(cams_s, sm.free_map, maps.coarse[0].origin_xy, res,
                                            centre, yaws, n, m)
    vol *= sm.free_volumes[key]
    peaks = top_hypotheses(vol, yaws, res, n, opt.top_k, opt.distinct_m,
                           np.deg2rad(opt.distinct_deg))
    timings["correlative"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    sel = _subsample(xy_s, cls, None, opt.max_points, rng)
    p_xy, p_cls, p_view, p_frame = xy_s[sel], cls[sel], view[sel], frame[sel]

    def associate(q: F64, q_class: I32, v: F64) -> tuple[F64, F64]:
        return maps.nearest(q, maps.layer_of(q_class, v))

    found: list[_Found] = []
    fitted: list[_Found] = []
    # ICP on an even share of the sample (every k-th point: all frames keep their share).
    k = max(1, -(-len(p_xy) // opt.icp_points))
    i_xy, i_cls, i_view = p_xy[::k], p_cls[::k], p_view[::k]
    # The peaks' ICP runs in lock-step (one association call per iteration for all of them;
    # each run the bits of ``icp_2d`` from its peak).
    fits = icp_2d_many(i_xy, i_cls, associate,
                       [Correction2D(peak.yaw, peak.t, centre) for peak in peaks], i_view,
                       opt.icp_radius_start_m, opt.icp_radius_end_m, opt.icp_iterations,
                       opt.icp_huber_m, opt.inlier_m)
    for peak, fit in zip(peaks, fits, strict=True):
        corr = fit.correction
        layer = maps.layer_of(p_cls, p_view @ rot2(corr.yaw).T)
        sc, dist = maps.fine_eval(corr.apply(p_xy), layer)
        fitted.append(_Found(corr, storey, 0.0, float(sc.mean()),
                             float((dist < opt.inlier_m).mean()), 1.0, peak.score,
                             corr.apply(cams_s), constraint=fit.constraint))
    timings["icp"] += time.perf_counter() - t0
    # The per-frame fit of the best rigid fits (the slow, sharp score), one per distinct place.
    t0 = time.perf_counter()

    def with_free(f: _Found) -> _Found:
        free, _ = free_space_fraction(f.cams_xy, seg, field_, opt.free_clearance_m,
                                      opt.enclosed_rays, opt.enclosed_min_hits,
                                      shell=sm.shell)
        return replace(f, free=free)

    for f in _by_key(fitted, lambda f: f.rigid_fit, with_free, lambda f: f.rigid_fit * f.free):
        if len(found) >= opt.rescore_top:
            break
        if all(_distinct(f, g, opt) for g in found):
            frame_fit, _, _, turn, moved = _frame_fit(f.corr, p_xy, p_cls, p_view, p_frame,
                                                      cams_s, maps, opt)
            seen, agree = _see_through(f.corr, turn, moved, p_xy, p_cls, p_view, p_frame, cams_s,
                                       seg, maps, opt)
            found.append(replace(f, fit=frame_fit, see_through=seen,
                                 see_through_power=opt.see_through_power, agreement=agree,
                                 agreement_power=opt.range_power))
    timings["rescore"] += time.perf_counter() - t0
    # Fold the shift into the correction: R (p + s - c) + c + t = R (p - (c - s)) + (c - s)
    # + (t + s).
    return [replace(f, corr=Correction2D(f.corr.yaw, f.corr.t + shift, f.corr.pivot - shift))
            for f in found]


def _score_at(init: Correction2D, storey: _Storey, sm: _StoreyMaps, p_xy: F64, p_cls: I32,
              p_view: F64, p_frame: I32, cams_xy: F64, opt: GlobalAlignOptions) -> _Found:
    """The real scan's ranking score at a placement near ``init``: ICP (as a peak of the
    search), then the per-frame fit, free share and see-through share (``p_*`` (M, ...) the
    points and ``cams_xy`` (N, 2) the cameras, levelled SLAM frame; ``init``'s frame)."""
    maps = sm.maps

    def associate(q: F64, q_class: I32, v: F64) -> tuple[F64, F64]:
        return maps.nearest(q, maps.layer_of(q_class, v))

    k = max(1, -(-len(p_xy) // opt.icp_points))
    fit = icp_2d(p_xy[::k], p_cls[::k], associate, init, p_view[::k], opt.icp_radius_start_m,
                 opt.icp_radius_end_m, opt.icp_iterations, opt.icp_huber_m, opt.inlier_m)
    corr = fit.correction
    layer = maps.layer_of(p_cls, p_view @ rot2(corr.yaw).T)
    sc, dist = maps.fine_eval(corr.apply(p_xy), layer)
    cams_w = corr.apply(cams_xy)
    free, _ = free_space_fraction(cams_w, sm.seg, sm.field_, opt.free_clearance_m,
                                  opt.enclosed_rays, opt.enclosed_min_hits, shell=sm.shell)
    frame_fit, _, _, turn, moved = _frame_fit(corr, p_xy, p_cls, p_view, p_frame, cams_xy, maps,
                                              opt)
    seen, agree = _see_through(corr, turn, moved, p_xy, p_cls, p_view, p_frame, cams_xy, sm.seg,
                               maps, opt)
    return _Found(corr, storey, frame_fit, float(sc.mean()), float((dist < opt.inlier_m).mean()),
                  free, 0.0, cams_w, seen, opt.see_through_power, fit.constraint, agree,
                  opt.range_power)


def _compose(a: Correction2D, b: Correction2D) -> Correction2D:
    """``a ∘ b`` (b first), with ``b``'s pivot."""
    t = rot2(a.yaw) @ (b.pivot + b.t - a.pivot) + a.pivot + a.t - b.pivot
    return Correction2D(a.yaw + b.yaw, t, b.pivot)


@dataclass(frozen=True)
class PlanAlias:
    """Another placement where the plan repeats what the best placement's scan saw
    (:func:`_plan_alias`).

    Attributes
    ----------
    floor_z: its storey's floor (m; None: plan without floors).
    yaw_deg: its yaw relative to the best placement (degrees, (-180, 180]).
    moved_m: mean distance between the cameras of the two placements (m).
    match: share of the plan points the best placement's scan saw that lie on a same-class wall
        of the plan (within ``alias_tol_m``) when moved to this placement (0-1).
    free_fraction: share of the moved cameras in free space (0-1).
    see_through: share of those plan points seen through a wall from the moved cameras (0-1).
    difference: ``(1 - match) + (1 - free_fraction) + max(0, see_through - s0)`` (``s0``: the
        ideal scan's share seen through walls at the best placement, grazing wall ends): what a
        perfect scan could tell apart; the aliases with the smallest difference (at most
        ``alias_max_difference``) get the real scan's score.
    score: the real scan's ranking score at this placement (ICP from it, then as a peak of the
        search: per-frame fit × free share × (1 - see-through) ** power).
    score_ratio: ``score`` / the best placement's score (the lower of its search score and its
        :func:`_score_at` score on the same points); at or above ``ambiguity_ratio`` the result
        is ambiguous. The larger of this ratio with and without the range agreement factor
        (``range_power``): where the plan repeats what the scan saw, the sharper term may add
        a flag, never lift one (Duplex_A seed 16: 0.91 without it, 0.79 with it, the best
        placement the wrong unit).
    fit_score, scan_free_fraction, scan_see_through: the real scan's per-frame fit, share of
        cameras in free space and share of points seen through walls at this placement (what
        the best placement must reach to be accepted; :func:`_alias_ambiguous`).
    vote: the discriminating-ray vote between the best placement and this alias
        (:func:`alias_range_vote`; None: not cast, the alias is not near-exact).
    """

    floor_z: float | None
    yaw_deg: float
    moved_m: float
    match: float
    free_fraction: float
    see_through: float
    difference: float
    score: float = 0.0
    score_ratio: float = 0.0
    fit_score: float = 0.0
    scan_free_fraction: float = 0.0
    scan_see_through: float = 0.0
    vote: RangeVote | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _plan_alias(best: _Found, scan: _Scan, sections: list[_Storey], plan: FloorPlan,
                storey_maps: dict[bytes, _StoreyMaps], opt: GlobalAlignOptions,
                rng: np.random.Generator) -> PlanAlias | None:
    """The placement, distinct from ``best``, where the plan looks most like what ``best``'s
    scan saw (a point-symmetric duplex, a repeated room): the scan's wall points are replaced by
    their nearest plan points under ``best`` (an ideal, noise- and drift-free scan of the same
    walls from the same cameras) and that ideal scan is searched over every storey like the
    real one (correlative search, ICP of the top ``alias_top`` peaks, same free-space factor).
    The ``alias_rescore`` placements where the plan repeats most closely then get the *real*
    scan's score (:func:`_score_at`): the search may have missed them, and drift can rank the
    truth below its alias (a duplex of two point-symmetric units: the wrong unit fitted better
    in 3 of 20 runs). The returned alias is the one whose real score is highest; the caller
    flags the result when that score is at least ``ambiguity_ratio`` of the best's, or
    ``alias_exact_ratio`` where the plan repeats almost exactly (:func:`_alias_ambiguous`); an
    alias that makes the result ambiguous is returned before one that does not.
    None: too few points, or no distinct placement within ``alias_max_difference``."""
    keep = _keep(scan, best.storey, opt)
    sm_best = storey_maps[_section_key(plan, best.storey)]
    xy, cls, frame = scan.xy[keep], scan.cls[keep], scan.frame[keep]
    if len(xy) < 20:
        return None
    sel = np.linspace(0, len(xy) - 1, min(len(xy), opt.alias_points)).astype(np.int64)
    xy, cls, frame = xy[sel], cls[sel], frame[sel]
    cams = best.cams_xy
    q = best.corr.apply(xy)
    layer = sm_best.maps.layer_of(cls, q - cams[frame])
    dist, closest = sm_best.maps.nearest(q, layer)
    on = dist < opt.inlier_m
    if on.sum() < 20:
        return None
    p_xy, p_cls, p_frame = closest[on], cls[on], frame[on]
    p_view = p_xy - cams[p_frame]
    # The ideal scan's own rays graze wall ends at the best placement too: only more counts.
    seen_here = see_through_fraction(cams[p_frame], p_xy, sm_best.seg,
                                     opt.see_through_margin_m,
                                     margin_from=opt.see_through_margin_from)[0]
    cands: list[tuple[float, Correction2D, _Storey, Correction2D, PlanAlias]] = []
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(opt.yaw_step_deg))
    done: set[bytes] = set()
    for storey in sections:
        key = _section_key(plan, storey)
        if key in done or key not in storey_maps:
            continue
        done.add(key)
        sm = storey_maps[key]
        shift = sm.centre - cams.mean(0)
        ps, cs = p_xy + shift, cams + shift
        occ = _subsample(ps, p_cls, 0.5 * opt.resolution_m, 40 * opt.max_points, rng)
        vol, res, n = score_volume(ps[occ], p_cls[occ], p_view[occ], sm.maps, sm.centre, yaws,
                                   sm.half, y_range_m=sm.half_y)
        vol *= _free_volume(cs, sm.free_map, sm.maps.coarse[0].origin_xy, res, sm.centre, yaws,
                            n, (vol.shape[1] - 1) // 2)
        peaks = top_hypotheses(vol, yaws, res, n, opt.alias_top, opt.distinct_m,
                               np.deg2rad(opt.distinct_deg))

        def associate(q_: F64, q_class: I32, v: F64, sm: _StoreyMaps = sm
                      ) -> tuple[F64, F64]:
            return sm.maps.nearest(q_, sm.maps.layer_of(q_class, v))

        fits = icp_2d_many(ps, p_cls, associate,
                           [Correction2D(peak.yaw, peak.t, sm.centre) for peak in peaks], p_view,
                           opt.icp_radius_start_m, 0.5 * opt.alias_tol_m, opt.icp_iterations,
                           opt.icp_huber_m, opt.alias_tol_m)
        for fit in fits:
            corr = fit.correction
            cams_w = corr.apply(cs)
            # The alias must be elsewhere: another storey, or moved / turned in this one (``corr``
            # moves the best placement's points; the identity is the best placement itself).
            yaw = float(np.rad2deg(np.angle(np.exp(1j * corr.yaw))))
            moved = float(np.linalg.norm(cams_w - cams, axis=1).mean())
            dz = (0.0 if storey.floor_z is None or best.storey.floor_z is None
                  else abs(storey.floor_z - best.storey.floor_z))
            if moved <= opt.distinct_m and abs(yaw) <= opt.distinct_deg and dz <= opt.distinct_z_m:
                continue
            moved_q = corr.apply(ps)
            match = float(sm.maps.fine_score_at(moved_q, sm.maps.layer_of(
                p_cls, p_view @ rot2(corr.yaw).T)).mean())
            # The difference only grows term by term, and a candidate above
            # ``alias_max_difference`` is never rescored: the costly terms only where needed.
            if (1.0 - match) > opt.alias_max_difference:
                continue
            free, _ = free_space_fraction(cams_w, sm.seg, sm.field_, opt.free_clearance_m,
                                          opt.enclosed_rays, opt.enclosed_min_hits,
                                          shell=sm.shell)
            if (1.0 - match) + (1.0 - free) > opt.alias_max_difference:
                continue
            seen = see_through_fraction(cams_w[p_frame], moved_q, sm.seg,
                                        opt.see_through_margin_m,
                                        margin_from=opt.see_through_margin_from)[0]
            diff = (1.0 - match) + (1.0 - free) + max(0.0, seen - seen_here)
            # ``corr`` takes the shifted points into the world: fold the shift in (as
            # :func:`_search_storey` does), then apply it after ``best``.
            in_world = Correction2D(corr.yaw, corr.t + shift, corr.pivot - shift)
            cands.append((diff, _compose(in_world, best.corr), storey, in_world,
                          PlanAlias(storey.floor_z, yaw, moved, match, free, seen, diff)))
    # The real scan where the plan repeats best: the search may have missed the place, or
    # drift may have ranked it below the alias.
    cands.sort(key=lambda c: c[0])
    out: PlanAlias | None = None
    every = np.flatnonzero(keep)
    every = every[np.linspace(0, len(every) - 1, min(len(every), opt.max_points)).astype(np.int64)]
    all_xy, all_cls, all_frame = scan.xy[every], scan.cls[every], scan.frame[every]
    all_view = scan.view[every]
    if not cands or cands[0][0] > opt.alias_max_difference:
        return None
    # The best placement scored the same way, on the same points (the search drew its own);
    # either of its two scores may be the lower one, and the lower decides (when in doubt,
    # flag: with the rescored one alone a Duplex_A run stayed silently wrong).
    rescored = _score_at(best.corr, best.storey, sm_best, all_xy, all_cls, all_view, all_frame,
                         scan.cams[:, :2], opt)
    best_score = min(best.score, rescored.score)
    best_plain = min(best.score_without_range, rescored.score_without_range)
    best_rays: tuple[F64, F64] | None = None
    for diff, corr, storey, image, alias in cands[:opt.alias_rescore]:
        if diff > opt.alias_max_difference:
            break
        f = _score_at(corr, storey, storey_maps[_section_key(plan, storey)], all_xy, all_cls,
                      all_view, all_frame, scan.cams[:, :2], opt)
        # With and without the range agreement: in an alias the plan nearly repeats, and the
        # sharper term may only add a flag (see ``PlanAlias.score_ratio``).
        ratio = max(f.score / best_score if best_score > 0 else 0.0,
                    f.score_without_range / best_plain if best_plain > 0 else 0.0)
        here = replace(alias, score=f.score, score_ratio=ratio, fit_score=f.fit,
                       scan_free_fraction=f.free, scan_see_through=f.see_through)
        if diff <= opt.alias_exact_difference and opt.alias_vote:
            # Where no ratio can tell: the rays where the plan differs vote.
            if best_rays is None:
                best_rays = _polished_points(rescored.corr, all_xy, all_cls, all_view,
                                             all_frame, scan.cams[:, :2], sm_best.maps, opt)
            q_b, c_b = best_rays
            here = replace(here, vote=alias_range_vote(
                c_b, q_b, image.apply(c_b), image.apply(q_b), all_frame, sm_best.seg,
                storey_maps[_section_key(plan, storey)].seg, opt.alias_vote_differ_m,
                opt.alias_vote_tol_m))
        if out is None or ((_alias_ambiguous(here, opt), ratio)
                           > (_alias_ambiguous(out, opt), out.score_ratio)):
            out = here
    return out


def _alias_ambiguous(alias: PlanAlias, opt: GlobalAlignOptions) -> bool:
    """Whether ``alias`` makes the result ambiguous: the real scan scores at least
    ``ambiguity_ratio`` of the best there, or the plan repeats what the best placement saw
    almost exactly (ideal difference at most ``alias_exact_difference``) and the real scan
    placed there would itself be accepted (per-frame fit at least ``min_score``, cameras in
    free space at least ``min_free_fraction``, points seen through walls at most
    ``max_see_through``), whatever the ratio.

    Why no ratio at a near-exact alias: the ideal difference is what a perfect scan could tell
    apart. At an exact repeat it is not 0 (the ICP tolerance, the fine score's width, the best
    placement's own cameras near walls): 0.03-0.08 at the 180 deg image of Duplex_A's two
    point-symmetric units (bench_global, 20 seeds each with 2 cm and 2 mm floor planes; median
    0.04). There a perfect scan scores the two alike and the real scan's gap between them is
    what drift, clutter and the local optima of ICP make of it: the real ratio at those aliases
    spread from 0.69 to 1.09 (docs/global_align.md, "Near-exact aliases"), and a 3 mm change
    of a floor plane moved seed 14 from >= 0.9 to 0.875 (placed 7.3 m off, unflagged, under the
    ratio threshold alone). The smallest ideal
    difference of an alias behind a right, unflagged placement on the generated worlds was
    0.107 (the 180 deg image of a corridor of jittered room widths); the limit, 0.1, sits
    nearer that side: a miss there costs a flag, a miss on the other a wrong placement.

    What does tell, at a near-exact alias: the rays where the plan differs (``alias_vote``,
    :attr:`PlanAlias.vote`, :func:`alias_range_vote`). When enough of them, from enough frames,
    back the best placement (:meth:`RangeVote.decides`), the alias makes the result ambiguous
    neither by the near-exact rule nor by its ratio (both drift's there); an exact repeat has
    next to no such rays, so its flag stays."""
    near_exact = alias.difference <= opt.alias_exact_difference
    if (near_exact and opt.alias_vote and alias.vote is not None
            and alias.vote.decides(opt)):
        return False  # the rays where the plan differs back the best placement
    if alias.score_ratio >= opt.ambiguity_ratio:
        return True
    return (near_exact
            and alias.fit_score >= opt.min_score
            and alias.scan_free_fraction >= opt.min_free_fraction
            and alias.scan_see_through <= opt.max_see_through)


def plan_ranges(cam_xy: F64, p_xy: F64, segments: F64, beyond_m: float,
                chunk: int = 256) -> F64:
    """The plan's range along each ray: the distance from the camera, along the ray through
    its point, to the first plan segment the ray crosses, looked for up to ``beyond_m`` past
    the point.

    Parameters
    ----------
    cam_xy: (M, 2) the camera of each point, metres (world); p_xy: (M, 2) the points.
    segments: (S, 4) the storey's plan section.
    beyond_m: how far past the point the ray goes (metres, >= 0).

    Returns
    -------
    (M,) ranges in metres; ``inf`` where the ray meets no segment (or has no length).
    """
    cam = np.asarray(cam_xy, dtype=np.float64).reshape(-1, 2)
    pts = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    out = np.full(len(pts), np.inf)
    if len(pts) == 0 or len(seg) == 0:
        return out
    ray = pts - cam
    length = np.linalg.norm(ray, axis=1)
    use = np.flatnonzero(length > 1e-9)
    reach = length[use] + beyond_m
    o_all = cam[use]
    d_all = ray[use] * (reach / length[use])[:, None]
    for k, _a, _e, s, cross in _ray_crossings(o_all, d_all, seg, chunk):
        out[use[k:k + chunk]] = (np.where(cross, s, np.inf).min(1, initial=np.inf)
                                 * reach[k:k + chunk])
    return out


@dataclass(frozen=True)
class RangeVote:
    """The discriminating-ray vote between a best placement and its alias
    (:func:`alias_range_vote`).

    Attributes
    ----------
    points: real wall/column points that took part (M).
    rays: discriminating rays: the plan ranges from the two placements differ by more than
        ``differ_m``.
    for_best, for_alias: discriminating rays whose measured range meets the best placement's
        (the alias's) plan range within ``tol_m``, and not the other's.
    frames: frames with at least one vote; frames_for_best: those where the best placement has
        more votes than the alias.
    share_low: the lower 95 % Wilson bound of ``for_best / (for_best + for_alias)`` (0 without
        votes).
    """

    points: int
    rays: int
    for_best: int
    for_alias: int
    frames: int
    frames_for_best: int
    share_low: float

    def decides(self, opt: GlobalAlignOptions) -> bool:
        """Whether the vote tells the best placement from the alias (``alias_vote_min_votes``,
        ``alias_vote_min_frames``, ``alias_vote_min_share``)."""
        return (self.for_best + self.for_alias >= opt.alias_vote_min_votes
                and self.frames >= opt.alias_vote_min_frames
                and self.share_low >= opt.alias_vote_min_share)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _wilson_low(k: int, n: int, z: float = 1.96) -> float:
    """Lower Wilson score bound of the share ``k / n`` (0 when ``n`` is 0)."""
    if n <= 0:
        return 0.0
    p = k / n
    centre = p + z * z / (2 * n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return float((centre - half) / (1 + z * z / n))


def alias_range_vote(cam_best: F64, q_best: F64, cam_alias: F64, q_alias: F64, frame: I32,
                     seg_best: F64, seg_alias: F64, differ_m: float = 0.3,
                     tol_m: float = 0.3) -> RangeVote:
    """Which of two placements the real ranges back, on the rays where the plan differs.

    The same real points (M) placed by the best placement (``cam_best``, ``q_best``: camera and
    point, world, (M, 2)) and by its alias (``cam_alias``, ``q_alias``), each in its storey's
    plan section (``seg_*``, (S, 4)). Each ray's plan range (:func:`plan_ranges`) is cast from
    both; where the two differ by more than ``differ_m`` (metres; one of them may meet no wall
    at all) the ray can tell the placements apart, and it votes for the one whose plan range
    its measured range (the camera-to-point distance, the same under both rigid placements)
    meets within ``tol_m`` (metres), when it meets only that one. Elsewhere the plan repeats
    itself and the ray says nothing. At an exact repeat (a point-symmetric duplex) few rays
    differ and their votes are drift's; where the plan differs in a wall the sensor saw (a
    room of another width, a door moved) the rays that met that wall vote, frame after frame.

    Returns
    -------
    RangeVote (``frame`` (M,) the frame of each point).
    """
    frame = np.asarray(frame, dtype=np.int64)
    measured = np.linalg.norm(np.asarray(q_best) - np.asarray(cam_best), axis=1)
    beyond = differ_m + tol_m
    r_best = plan_ranges(cam_best, q_best, seg_best, beyond)
    r_alias = plan_ranges(cam_alias, q_alias, seg_alias, beyond)
    both = np.isfinite(r_best) & np.isfinite(r_alias)
    gap = np.abs(np.where(both, r_best, 0.0) - np.where(both, r_alias, 0.0))
    differ = np.where(both, gap > differ_m, np.isfinite(r_best) | np.isfinite(r_alias))
    ok_best = np.abs(r_best - measured) <= tol_m
    ok_alias = np.abs(r_alias - measured) <= tol_m
    vote_best = differ & ok_best & ~ok_alias
    vote_alias = differ & ok_alias & ~ok_best
    n_best = int(vote_best.sum())
    n_alias = int(vote_alias.sum())
    voted = vote_best | vote_alias
    frames = np.unique(frame[voted])
    per_best = np.bincount(frame[vote_best], minlength=int(frame.max(initial=0)) + 1)
    per_alias = np.bincount(frame[vote_alias], minlength=int(frame.max(initial=0)) + 1)
    return RangeVote(len(frame), int(differ.sum()), n_best, n_alias, len(frames),
                     int((per_best[frames] > per_alias[frames]).sum()),
                     _wilson_low(n_best, n_best + n_alias))


def _polished_points(corr: Correction2D, p_xy: F64, p_cls: I32, p_view: F64, p_frame: I32,
                     cams_xy: F64, maps: PlanMaps, opt: GlobalAlignOptions) -> tuple[F64, F64]:
    """Each point (M, 2) and its camera (M, 2), world, under ``corr`` polished as for the
    see-through share (:func:`_see_through_rays`: the mean of the frames' best turns and
    shifts, then each frame turned by its own best turn) but without the windows' ICP: the
    alias vote reads the rays as it was measured with (docs/global_align.md, "The
    discriminating-ray vote")."""
    _, _, _, turn, shift = _frame_fit(corr, p_xy, p_cls, p_view, p_frame, cams_xy, maps, opt)
    return _see_through_rays(corr, turn, shift, p_xy, p_cls, p_view, p_frame, cams_xy, maps, opt,
                             windows=False)


def _free_map(segments: F64, bounds: tuple[float, float, float, float],
              opt: GlobalAlignOptions, shell: F64 | None = None) -> NDArray[np.float32]:
    """(H, W) 1 where a camera may stand, on the coarse grid of the storey's maps (same bounds,
    margin 3 m, ``resolution_m``): inside the building (at least ``enclosed_min_hits`` of
    ``enclosed_rays`` straight lines from the pixel meet a wall pixel of the shell (S', 4;
    None: ``segments``), the raster twin of :func:`free_space_fraction`'s rays, so that windows
    and doors, gaps in a plan section, do not let the outside in) and at least
    ``free_clearance_m`` from every wall of ``segments`` (S, 4)."""
    import cv2

    dist = DistanceField.from_segments(segments, opt.resolution_m, bounds, 3.0).distance_m
    around = (dist if shell is None
              else DistanceField.from_segments(shell, opt.resolution_m, bounds, 3.0).distance_m)
    wall = (around <= opt.resolution_m).astype(np.uint8)
    h, w = wall.shape
    size = int(np.ceil(np.hypot(h, w))) + 2
    pad = np.zeros((size, size), np.uint8)
    r0, c0 = (size - h) // 2, (size - w) // 2
    pad[r0:r0 + h, c0:c0 + w] = wall
    centre = ((size - 1) / 2.0, (size - 1) / 2.0)
    hits = np.zeros((size, size), np.int32)
    for k in range(opt.enclosed_rays):
        # Turn the image so that ray k points along +u, look ahead along each row, turn back.
        ang = 360.0 * (k + 0.5) / opt.enclosed_rays
        fwd = cv2.getRotationMatrix2D(centre, -ang, 1.0)
        turned = cv2.warpAffine(pad, fwd, (size, size), flags=cv2.INTER_NEAREST)
        ahead = np.flip(np.maximum.accumulate(np.flip(turned, 1), axis=1), 1)
        back = cv2.warpAffine(ahead, cv2.invertAffineTransform(fwd), (size, size),
                              flags=cv2.INTER_NEAREST)
        hits += back
    inside = hits[r0:r0 + h, c0:c0 + w] >= opt.enclosed_min_hits
    return (inside & (dist >= opt.free_clearance_m)).astype(np.float32)


def _free_volume(cams_xy: F64, free_map: NDArray[np.float32], origin: F64, res: float,
                 pivot: F64, yaws: F64, n: int, m: int | None = None) -> NDArray[np.float32]:
    """(Y, 2m+1, 2n+1) share of the cameras (N, 2) on free pixels of ``free_map`` after each
    correction ``R(yaw)(c - pivot) + pivot + t`` of the correlative grid (as
    :func:`.correlative.score_volume` indexes it; ``m``: the grid's half-height in cells, None:
    ``n``)."""
    import cv2

    from bimcap.registration.correlative import _crop

    m = n if m is None else m
    out = np.zeros((len(yaws), 2 * m + 1, 2 * n + 1), dtype=np.float32)
    rel = cams_xy - pivot
    for k, yaw in enumerate(yaws):
        c = rel @ rot2(float(yaw)).T + pivot
        uv = np.round((c - origin) / res).astype(np.int64)
        u0, v0 = uv.min(0)
        u1, v1 = uv.max(0)
        templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
        np.add.at(templ, (uv[:, 1] - v0, uv[:, 0] - u0), 1.0)
        img = _crop(free_map, v0 - m, v1 + m + 1, u0 - n, u1 + n + 1)
        out[k] = cv2.matchTemplate(img, templ, cv2.TM_CCORR) / len(c)
    return out


def _frame_fit(corr: Correction2D, p_xy: F64, p_cls: I32, p_view: F64, p_frame: I32,
               cams_xy: F64, maps: PlanMaps, opt: GlobalAlignOptions,
               frame_fits: F64 | None = None) -> tuple[float, F64, F64, float, F64]:
    """Mean over frames of each frame's best fine score when the frame alone may turn by up to
    ``±frame_yaw_deg`` about its camera and shift by up to ``±frame_shift_m``: a drifted
    trajectory is not rigid (per-frame rotation noise, a translation walk), so the rigid fit
    blurs the right placement as much as an alias; frame by frame the right one fits sharply.

    ``p_*`` (M, ...) the points before ``corr``, ``cams_xy`` (N, 2) the cameras before it;
    ``frame_fits`` (N,), when given, is filled with each frame's fit (NaN: a frame without
    points).

    Returns
    -------
    The fit (0-1), and each point (M, 2) and its frame's camera (M, 2) where the frame's best
    turn without a shift puts them (world): the turn takes out the per-frame rotation noise;
    the shift, a smooth walk in a drifted trajectory, is left to the rigid placement (shifted
    frames would pull their points back inside an alias room's walls); then the mean of the
    frames' best turns (radians) and shifts (2,): the rigid placement's own error.
    """
    n = len(cams_xy)
    q = corr.apply(p_xy)
    cam = corr.apply(cams_xy)[p_frame]
    view = p_view @ rot2(corr.yaw).T
    count = np.bincount(p_frame, minlength=n).astype(np.float64)
    best = np.full(n, -1.0)
    best_still = np.full(n, -1.0)  # the best of the frame's turns without a shift
    turn = np.zeros(n)
    best_turn, best_shift = np.zeros(n), np.zeros((n, 2))
    step = opt.frame_yaw_step_deg
    deltas = np.deg2rad(np.arange(-opt.frame_yaw_deg, opt.frame_yaw_deg + 0.5 * step, step))
    deltas = deltas[np.argsort(np.abs(deltas), kind="stable")]  # ties go to the smaller turn
    s = opt.frame_shift_m
    shifts = [np.zeros(2)] + ([np.array([dx, dy]) for dx in (-s, 0.0, s) for dy in (-s, 0.0, s)
                               if dx or dy] if s > 0 else [])
    for d in deltas:
        r = rot2(float(d))
        qd = (q - cam) @ r.T + cam
        layer = maps.layer_of(p_cls, view @ r.T)
        for sh in shifts:
            sc = maps.fine_score_at(qd + sh, layer)
            mean = np.bincount(p_frame, weights=sc, minlength=n) / np.maximum(count, 1.0)
            better = mean > best
            best[better], best_turn[better], best_shift[better] = mean[better], d, sh
            if not sh.any():
                better = mean > best_still
                best_still[better], turn[better] = mean[better], d
    has = count > 0
    if frame_fits is not None:
        frame_fits[:] = np.where(has, np.maximum(best, 0.0), np.nan)
    c, s_ = np.cos(turn)[p_frame], np.sin(turn)[p_frame]
    rel = q - cam
    q_turned = cam + np.c_[c * rel[:, 0] - s_ * rel[:, 1], s_ * rel[:, 0] + c * rel[:, 1]]
    if not has.any():
        return 0.0, q_turned, cam, 0.0, np.zeros(2)
    return (float(np.maximum(best[has], 0.0).mean()), q_turned, cam,
            float(best_turn[has].mean()), best_shift[has].mean(0))


_IDENTITY = Correction2D(0.0, np.zeros(2), np.zeros(2))


def _window_polish(opt: GlobalAlignOptions) -> WindowPolish:
    """The window polish of the see-through test (``see_through_window_*``)."""
    return WindowPolish(window_frames=opt.see_through_window_frames,
                        max_yaw_deg=opt.see_through_window_yaw_deg,
                        max_shift_m=opt.see_through_window_shift_m)


def _see_through_rays(corr: Correction2D, turn: float, shift: F64, p_xy: F64, p_cls: I32,
                      p_view: F64, p_frame: I32, cams_xy: F64, maps: PlanMaps,
                      opt: GlobalAlignOptions, windows: bool = True) -> tuple[F64, F64]:
    """Each point (M, 2) and its camera (M, 2), world, as the see-through test reads them: the
    placement ``corr`` polished by the mean turn (about the cameras' centroid) and shift of its
    frames' best per-frame fits, then (``windows`` and ``see_through_window_frames`` > 0) each
    window of frames moved by its own bounded rigid ICP (:func:`.window_polish.polish_windows`:
    the trajectory's translation walk), each frame then turned by its own best turn."""
    centre = corr.apply(cams_xy).mean(0)
    r = rot2(turn)
    t = r @ (corr.pivot + corr.t - centre) + centre + shift - corr.pivot
    polished = Correction2D(corr.yaw + turn, t, corr.pivot)
    frame_opt = replace(opt, frame_shift_m=0.0)
    if windows and opt.see_through_window_frames > 0:
        q, view, cams, _ = polish_windows(
            polished.apply(p_xy), p_cls, p_view @ rot2(polished.yaw).T, p_frame,
            polished.apply(cams_xy), maps, _window_polish(opt))
        _, q_turned, cam, _, _ = _frame_fit(_IDENTITY, q, p_cls, view, p_frame, cams, maps,
                                            frame_opt)
    else:
        _, q_turned, cam, _, _ = _frame_fit(polished, p_xy, p_cls, p_view, p_frame, cams_xy,
                                            maps, frame_opt)
    return q_turned, cam


def _see_through(corr: Correction2D, turn: float, shift: F64, p_xy: F64, p_cls: I32,
                 p_view: F64, p_frame: I32, cams_xy: F64, segments: F64, maps: PlanMaps,
                 opt: GlobalAlignOptions, windows: bool = False) -> tuple[float, float]:
    """The share of points seen through a wall (:func:`see_through_fraction`) and the range
    agreement (:func:`range_agreement`, 1 when ``range_power`` is 0: not computed) for the
    placement ``corr`` polished as :func:`_see_through_rays` says (``turn`` and ``shift``: the
    mean of its frames' best turns and shifts; ``windows``: each window of frames by its own
    ICP too, :func:`_window_see_through`): the negative evidence must not punish the rigid
    placement's residual error or the per-frame yaw noise (a ray that grazes a wall's end),
    which differ between a placement and its exact alias."""
    q_turned, cam = _see_through_rays(corr, turn, shift, p_xy, p_cls, p_view, p_frame, cams_xy,
                                      maps, opt, windows)
    seen = see_through_fraction(cam, q_turned, segments, opt.see_through_margin_m,
                                margin_from=opt.see_through_margin_from)[0]
    agree = (range_agreement(cam, q_turned, segments, opt.range_tol_m)[0]
             if opt.range_power > 0 else 1.0)
    return seen, agree


def _window_see_through(f: _Found, scan: _Scan, sm: _StoreyMaps, opt: GlobalAlignOptions
                        ) -> tuple[float, float]:
    """The see-through share of the placement ``f`` measured twice on the same points (at most
    ``max_points`` of the scan's wall/column points of its storey, every k-th): as the ranking
    measures it, and with each window of frames polished by its own bounded rigid ICP
    (:func:`.window_polish.polish_windows`). Returns (ranking's, windowed)."""
    keep = np.flatnonzero(_keep(scan, f.storey, opt))
    keep = keep[::max(1, -(-len(keep) // opt.max_points))]
    if not len(keep):
        return f.see_through, f.see_through
    xy, cls, view, frame = scan.xy[keep], scan.cls[keep], scan.view[keep], scan.frame[keep]
    cams = scan.cams[:, :2]
    _, _, _, turn, shift = _frame_fit(f.corr, xy, cls, view, frame, cams, sm.maps, opt)
    rigid, _ = _see_through(f.corr, turn, shift, xy, cls, view, frame, cams, sm.seg, sm.maps,
                            replace(opt, range_power=0.0))
    windowed, _ = _see_through(f.corr, turn, shift, xy, cls, view, frame, cams, sm.seg, sm.maps,
                               replace(opt, range_power=0.0), windows=True)
    return rigid, windowed


@dataclass(frozen=True)
class DriftSeeThrough:
    """The answer to a placement refused for its see-through alone (:func:`global_align`):
    the see-through share of the best ranked placements measured again with each window of
    frames polished by its own bounded rigid ICP (:mod:`.window_polish`; a drifted
    trajectory's walk), on the same points as without.

    Attributes
    ----------
    rigid, windowed: (K,) the share of each of the best K distinct placements (ranked order)
        without and with the windows' polish (0-1).
    scores: (K,) their scores with the windowed share in place of the ranking's (the factor
        ``((1 - windowed) / (1 - see_through)) ** see_through_power``).
    accepted: whether the best placement was taken on it: its windowed share at most
        ``max_see_through``, still the best of the rescored placements, the second-best at
        most ``see_through_window_max_ratio`` of it, and no near-exact plan alias.
    """

    rigid: list[float]
    windowed: list[float]
    scores: list[float]
    accepted: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _drift_see_through(ranked: list[_Found], scan: _Scan, plan: FloorPlan,
                       storey_maps: dict[bytes, _StoreyMaps], alias: PlanAlias | None,
                       opt: GlobalAlignOptions) -> DriftSeeThrough:
    """:class:`DriftSeeThrough` of the best ``report_top`` ranked placements."""
    rigid, windowed, scores = [], [], []
    for f in ranked[:max(opt.report_top, 2)]:
        r, w = _window_see_through(f, scan, storey_maps[_section_key(plan, f.storey)], opt)
        factor = ((1.0 - w) / (1.0 - f.see_through)) ** opt.see_through_power \
            if f.see_through < 1.0 else 1.0
        rigid.append(r)
        windowed.append(w)
        scores.append(f.score * factor)
    best = scores[0]
    second = max(scores[1:], default=0.0)
    near_exact = alias is not None and alias.difference <= opt.alias_exact_difference
    accepted = (windowed[0] <= opt.max_see_through and best > 0
                and second <= opt.see_through_window_max_ratio * best and not near_exact)
    return DriftSeeThrough(rigid, windowed, scores, bool(accepted))


@dataclass(frozen=True)
class TrimmedFit:
    """The answer to a placement refused for its fit alone (:func:`global_align`): its fit
    measured again on the frames whose walls exist (``fit_trim_frames``).

    Attributes
    ----------
    fit: the per-frame fit over every frame with points (0-1), on the points measured here
        (at most ``max_points`` of the storey's wall/column points, every k-th).
    trimmed: the same without the worst-fitting ``frames_set_aside`` frames (0-1).
    frames, frames_set_aside: frames with points, and those set aside.
    accepted: whether the placement was taken on it: ``trimmed`` at least ``min_score`` and
        the second-best scoring at most ``fit_trim_max_ratio`` of the best.
    """

    fit: float
    trimmed: float
    frames: int
    frames_set_aside: int
    accepted: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _trimmed_fit(f: _Found, scan: _Scan, sm: _StoreyMaps, ratio: float,
                 opt: GlobalAlignOptions) -> TrimmedFit:
    """:class:`TrimmedFit` of placement ``f`` (``ratio``: second-best / best score)."""
    keep = np.flatnonzero(_keep(scan, f.storey, opt))
    keep = keep[::max(1, -(-len(keep) // opt.max_points))]
    per = np.full(len(scan.cams), np.nan)
    if len(keep):
        _frame_fit(f.corr, scan.xy[keep], scan.cls[keep], scan.view[keep], scan.frame[keep],
                   scan.cams[:, :2], sm.maps, opt, frame_fits=per)
    per = np.sort(per[np.isfinite(per)])
    if not len(per):
        return TrimmedFit(0.0, 0.0, 0, 0, False)
    drop = int(np.floor(opt.fit_trim_frames * len(per)))
    trimmed = float(per[drop:].mean())
    accepted = trimmed >= opt.min_score and ratio <= opt.fit_trim_max_ratio
    return TrimmedFit(float(per.mean()), trimmed, len(per), drop, bool(accepted))


def _distinct(a: _Found, b: _Found, opt: GlobalAlignOptions) -> bool:
    dyaw = abs(np.rad2deg(np.angle(np.exp(1j * (a.corr.yaw - b.corr.yaw)))))
    dz = (0.0 if a.storey.floor_z is None or b.storey.floor_z is None
          else abs(a.storey.floor_z - b.storey.floor_z))
    moved = float(np.linalg.norm(a.cams_xy - b.cams_xy, axis=1).mean())
    return moved > opt.distinct_m or dyaw > opt.distinct_deg or dz > opt.distinct_z_m


def _by_key(items: list[_T], bound: Callable[[_T], float], complete: Callable[[_T], _T],
            key: Callable[[_T], float]) -> Iterator[_T]:
    """``items`` in the order of ``sorted(complete(f) for f in items, key=lambda f: -key(f))``
    (stable), yielded lazily: ``complete(f)`` (costly: the free space of a placement) is
    computed only for the items that come up, ``bound(f) >= key(complete(f))`` standing in for
    the key until then. A consumer that stops after a few gets the same ones as the full sort."""
    heap = [(-float(bound(f)), i, False, f) for i, f in enumerate(items)]
    heapq.heapify(heap)
    while heap:
        _, i, exact, f = heapq.heappop(heap)
        if exact:
            yield f
        else:
            g = complete(f)
            heapq.heappush(heap, (-float(key(g)), i, True, g))


def _transform(f: _Found, gravity: F64, scan_floor_z: float | None) -> F64:
    """(4, 4) ``world_from_slam`` of a hypothesis."""
    g = np.eye(4)
    g[:3, :3] = gravity
    c = f.corr.matrix()
    m = np.eye(4)
    m[:2, :2] = c[:2, :2]
    m[:2, 3] = c[:2, 2]
    if f.storey.floor_z is not None and scan_floor_z is not None:
        m[2, 3] = f.storey.floor_z - scan_floor_z
    return m @ g


def _search_all(scan: _Scan, sections: list[_Storey], plan: FloorPlan,
                storey_maps: dict[bytes, _StoreyMaps], opt: GlobalAlignOptions,
                rng: np.random.Generator, timings: dict[str, float],
                maps_cache: dict[bytes, Any] | None = None
                ) -> tuple[list[_Found], list[dict[str, Any]]]:
    """Steps 2-4 on every storey of ``sections``: the placements found and, per storey, its
    floor, segments and best score. ``storey_maps`` is filled with the storeys' maps (by
    :func:`_section_key`) as they are built, and reused when given; ``maps_cache`` (by
    :func:`_maps_key`; None: none) keeps them beyond this alignment."""
    found: list[_Found] = []
    storeys = []
    searched: dict[bytes, list[_Found]] = {}
    for storey in sections:
        # A storey whose plan section and height repeat one searched already (a tower of
        # identical floors) gets that storey's placements: the search would find the same.
        key = _section_key(plan, storey)
        if key in searched:
            here = [replace(f, storey=storey) for f in searched[key]]
        else:
            if key not in storey_maps:
                t0 = time.perf_counter()
                storey_maps[key] = _cached_storey_maps(storey, plan, opt, maps_cache)
                timings["maps"] += time.perf_counter() - t0
            here = searched[key] = _search_storey(scan, storey, storey_maps[key], opt, rng,
                                                  timings)
        storeys.append({"floor_z": storey.floor_z, "segments": len(storey.rows),
                        "best_score": max((f.score for f in here), default=0.0)})
        found += here
    return found, storeys


# The plan wall that a placement's seen-through rays cross (a wall missing as built); the
# missing-wall retry (:mod:`.missing_wall`) and the turned search's skip both read it.


@dataclass(frozen=True)
class SeenThroughWall:
    """The plan wall that most of the seen-through rays cross at a placement.

    Attributes
    ----------
    rows: (K,) its segment rows in the plan (its faces).
    segments: (K, 4) those segments, ``x1 y1 x2 y2`` metres (world).
    share: share of the seen-through points whose ray crosses it (0-1).
    see_through: share of the wall/column points seen through any plan wall (0-1).
    see_through_without: the same without this wall (0-1).
    """

    rows: NDArray[np.int64]
    segments: F64
    share: float
    see_through: float
    see_through_without: float

    def to_dict(self) -> dict[str, Any]:
        return {"rows": [int(r) for r in self.rows],
                "segments": np.round(self.segments, 3).tolist(), "share": self.share,
                "see_through": self.see_through, "see_through_without": self.see_through_without}

    def describe(self) -> str:
        ends = ", ".join(f"({s[0]:.2f}, {s[1]:.2f})-({s[2]:.2f}, {s[3]:.2f})"
                         for s in self.segments)
        return (f"{self.see_through:.0%} of the points were seen through the BIM's walls, "
                f"{self.share:.0%} of them through the one wall with face(s) {ends} m (missing "
                f"as built?); {self.see_through_without:.0%} without it")


def section_rows(plan: FloorPlan, floor_z: float | None, cut_m: float = 1.0
                 ) -> NDArray[np.int64]:
    """(S',) the plan's segment rows at ``cut_m`` above the floor ``floor_z`` (all of them for
    a plan without heights or an unknown floor)."""
    n = len(plan.segments)
    if plan.segment_z is None or floor_z is None:
        return np.arange(n)
    zc = floor_z + cut_m
    return np.flatnonzero((plan.segment_z[:, 0] <= zc) & (zc <= plan.segment_z[:, 1]))


def _wall_faces(seg: F64, k: int, max_thickness_m: float = MAX_WALL_THICKNESS_M,
                max_gap_m: float = MAX_DOOR_GAP_M) -> NDArray[np.int64]:
    """Indices into ``seg`` (S, 4) of the faces of the wall of segment ``k``: ``k`` and the
    segments parallel to it (within 5°), at most ``max_thickness_m`` from its line and
    overlapping it, or the ``max_gap_m`` beyond either of its ends, along its length (the
    pieces of one wall on both sides of a door)."""
    a, b = seg[k, :2], seg[k, 2:]
    length = float(np.linalg.norm(b - a))
    if length < 1e-9:
        return np.array([k])
    u = (b - a) / length
    n = np.array([-u[1], u[0]])
    d = seg[:, 2:] - seg[:, :2]
    lens = np.linalg.norm(d, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        parallel = np.abs(d @ u) >= np.cos(np.deg2rad(5.0)) * lens
    off = np.abs(np.c_[(seg[:, :2] - a) @ n, (seg[:, 2:] - a) @ n]).max(1)
    s0, s1 = (seg[:, :2] - a) @ u, (seg[:, 2:] - a) @ u
    overlap = (np.minimum(np.maximum(s0, s1), length + max_gap_m)
               - np.maximum(np.minimum(s0, s1), -max_gap_m))
    faces = parallel & (lens > 1e-9) & (off <= max_thickness_m) & (overlap > 0.1)
    faces[k] = True
    return np.flatnonzero(faces)


def polished_rays(world_from_cam: F64, samples: SemanticSamples, plan: FloorPlan,
                  floor_z: float | None, options: GlobalAlignOptions | None = None,
                  maps_cache: dict[bytes, Any] | None = None
                  ) -> tuple[NDArray[np.int64], F64, F64]:
    """The rays of the wall/column points as the global alignment's see-through test reads them
    at the placement ``world_from_cam`` (N, 7, TUM order, world frame, level): the storey
    whose floor is nearest ``floor_z`` (its section and wall band), each frame levelled by its
    floor, the placement polished by its frames' mean best turn and shift, each window of
    frames moved by its own bounded ICP and each frame turned by its own best turn
    (``bimcap.registration.global_align._see_through_rays``; at most ``max_points`` points,
    every k-th). A drifted trajectory's rotation and walk spread the rigid placement's rays
    over every wall (pipeline seed 13: 38 % of the seen-through points crossed the wall missing
    as built at the rigid placement, 67 % polished). ``maps_cache``: the storeys' maps kept by
    an alignment of ``plan`` (:func:`.global_align.global_align`), reused; None: built here.

    Returns
    -------
    The storey's segment rows (S,) in ``plan``, and each ray's camera (M, 2) and point (M, 2)
    (world, metres).
    """
    opt = GlobalAlignOptions() if options is None else options
    sections = _storeys(plan, opt.plan_cut_height_m)
    storey = min(sections, key=lambda st: 0.0 if st.floor_z is None or floor_z is None
                 else abs(st.floor_z - floor_z))
    sm = _cached_storey_maps(storey, plan, opt, maps_cache)
    scan = _scan(np.asarray(world_from_cam, np.float64), samples, opt.frame_level_max_deg)
    keep = np.flatnonzero(_keep(scan, storey, opt))
    keep = keep[::max(1, -(-len(keep) // opt.max_points))]
    xy, cls, view, frame = scan.xy[keep], scan.cls[keep], scan.view[keep], scan.frame[keep]
    cams = scan.cams[:, :2]
    if not len(xy):
        return storey.rows, np.zeros((0, 2)), np.zeros((0, 2))
    _, _, _, turn, shift = _frame_fit(_IDENTITY, xy, cls, view, frame, cams, sm.maps, opt)
    q, cam = _see_through_rays(_IDENTITY, turn, shift, xy, cls, view, frame, cams, sm.maps, opt)
    return storey.rows, cam, q


def dominant_seen_through_wall(world_from_cam: F64, samples: SemanticSamples, plan: FloorPlan,
                               floor_z: float | None, options: GlobalAlignOptions | None = None,
                               polished: bool = False,
                               maps_cache: dict[bytes, Any] | None = None
                               ) -> SeenThroughWall | None:
    """The plan wall that the most seen-through rays cross at the placement ``world_from_cam``
    (N, 7, TUM order, world frame): each wall/column point's ray from its camera, on the storey
    of ``floor_z``, crossed as :func:`see_through_fraction` counts it (``options``' margin);
    the rays as the cameras see them (``polished`` off) or as the global alignment's
    see-through test reads them (:func:`polished_rays`). None when no point is seen through a
    wall."""
    opt = GlobalAlignOptions() if options is None else options
    if polished:
        rows, cam, p = polished_rays(world_from_cam, samples, plan, floor_z, opt, maps_cache)
        seg = np.asarray(plan.segments, np.float64)[rows]
        if not len(p) or not len(seg):
            return None
    else:
        rows = section_rows(plan, floor_z)
        seg = np.asarray(plan.segments, np.float64)[rows]
        cams, pts = [], []
        for c in ("wall", "column"):
            fr = getattr(samples, f"{c}_frame")
            if len(fr):
                cams.append(world_from_cam[fr, :2])
                pts.append(transform_points(world_from_cam[fr],
                                            getattr(samples, f"{c}_p_in_cam"))[:, :2])
        if not pts or not len(seg):
            return None
        cam, p = np.concatenate(cams), np.concatenate(pts)

    def seen(s: F64, c: F64, q: F64) -> tuple[float, NDArray[np.bool_]]:
        return see_through_fraction(c, q, s, opt.see_through_margin_m,
                                    margin_from=opt.see_through_margin_from)

    total, flags = seen(seg, cam, p)
    if not flags.any():
        return None
    # The most-crossed segment, counted on at most MAX_COUNTED of the seen-through points.
    some = np.flatnonzero(flags)[::max(1, int(flags.sum()) // MAX_COUNTED)]
    _, counts = see_through_counts(cam[some], p[some], seg, opt.see_through_margin_m,
                                   margin_from=opt.see_through_margin_from)
    faces = _wall_faces(seg, int(np.argmax(counts)))
    crossing = seen(seg[faces], cam[flags], p[flags])[1]
    keep = np.ones(len(seg), bool)
    keep[faces] = False
    return SeenThroughWall(rows=rows[faces], segments=seg[faces],
                           share=float(crossing.mean()), see_through=total,
                           see_through_without=seen(seg[keep], cam, p)[0])


def _seen_through_wall(f: _Found, poses: F64, gravity: F64, scan_floor_z: float | None,
                       samples: SemanticSamples, plan: FloorPlan, opt: GlobalAlignOptions,
                       maps_cache: dict[bytes, Any]) -> SeenThroughWall | None:
    """The plan wall that most of placement ``f``'s seen-through rays cross
    (:func:`dominant_seen_through_wall` at ``f``'s placement of ``poses`` (N, 7,
    the SLAM frame), the rays polished; None when none is seen through)."""

    placed = matrix_to_pose(_transform(f, gravity, scan_floor_z) @ pose_to_matrix(poses))
    return dominant_seen_through_wall(placed, samples, plan, f.storey.floor_z, opt,
                                      polished=True, maps_cache=maps_cache)


def _fits(f: _Found, opt: GlobalAlignOptions) -> bool:
    """Whether placement ``f`` fits well enough by its scores (``min_score``,
    ``min_free_fraction``), its see-through aside."""
    return f.fit >= opt.min_score and f.free >= opt.min_free_fraction


def _fails(f: _Found, opt: GlobalAlignOptions) -> bool:
    """Whether placement ``f`` fits too badly to be taken (:func:`_fits`, ``max_see_through``)."""
    return not _fits(f, opt) or f.see_through > opt.max_see_through


def global_align(
    slam_from_cam: ArrayLike,
    samples: SemanticSamples,
    plan: FloorPlan,
    options: GlobalAlignOptions | None = None,
    maps_cache: dict[bytes, Any] | None = None,
) -> GlobalAlignResult:
    """Place a trajectory given in its own frame in the BIM (see the module docstring).

    Parameters
    ----------
    slam_from_cam: (N, 7) poses in the SLAM frame, TUM order.
    samples: the labelled points of every frame, camera frame (the front end's samples).
    plan: segments and floor/ceiling heights of the BIM, every storey.
    options: settings; default :class:`GlobalAlignOptions`.
    maps_cache: optional dict in which the storeys' maps are kept, to reuse them in a later
        alignment with the same options on a plan that shares storeys (the missing-wall retry,
        :func:`.missing_wall.align_without_missing_wall`: the same plan without one wall);
        None: built for this call only. The same maps, bit for bit, either way.

    Returns
    -------
    GlobalAlignResult with ``poses`` = ``world_from_slam ∘ slam_from_cam`` of the best
    hypothesis.

    Raises
    ------
    AmbiguousAlignmentError
        The best two distinct hypotheses score alike and ``accept_ambiguous`` is off.
    GlobalAlignmentError
        No hypothesis at all, or the best one fits badly.
    """
    opt = GlobalAlignOptions() if options is None else options
    t_start = time.perf_counter()
    timings = dict.fromkeys(("gravity", "maps", "correlative", "icp", "rescore"), 0.0)
    poses = np.asarray(slam_from_cam, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 7 or len(poses) == 0 or not np.isfinite(poses).all():
        raise RegistrationInputError(f"must be finite (N>0, 7), got {poses.shape}", None,
                                     "slam_from_cam")
    samples.check_frames(len(poses))
    rng = np.random.default_rng(opt.seed)
    # 1. gravity.
    t0 = time.perf_counter()
    gravity = _gravity(poses, samples) if opt.level_from_floor else np.eye(3)
    tilt = float(np.rad2deg(Rotation.from_matrix(gravity).magnitude()))
    applied = tilt > opt.gravity_min_tilt_deg
    if not applied:
        gravity = np.eye(3)
    g4 = np.eye(4)
    g4[:3, :3] = gravity
    levelled = matrix_to_pose(g4 @ pose_to_matrix(poses))
    timings["gravity"] = time.perf_counter() - t0
    scan = _scan(levelled, samples, opt.frame_level_max_deg)
    # 2.-4. every storey.
    sections = _storeys(plan, opt.plan_cut_height_m)
    storey_maps: dict[bytes, _StoreyMaps] = {}
    maps_cache = {} if maps_cache is None else maps_cache
    turned = opt.frame_yaw is FrameYaw.ALWAYS
    if turned:
        t0 = time.perf_counter()
        scan = _turned(scan, _frame_yaws(scan, opt))
        timings["frame_yaw"] = time.perf_counter() - t0
    found, storeys = _search_all(scan, sections, plan, storey_maps, opt, rng, timings, maps_cache)
    wall = None
    if opt.frame_yaw is FrameYaw.ON_REFUSAL and found:
        first = max(found, key=lambda f: f.score)
        if (_fails(first, opt) and _fits(first, opt)
                and opt.frame_yaw_wall_share <= 1.0):
            # Refused for its see-through alone: does one plan wall explain it (a wall
            # missing as built: not the frames' yaw errors, and the missing-wall retry's case)?
            t0 = time.perf_counter()
            wall = _seen_through_wall(first, poses, gravity, scan.floor_z, samples, plan, opt,
                                      maps_cache)
            timings["frame_yaw_wall"] = time.perf_counter() - t0
    if (opt.frame_yaw is FrameYaw.ON_REFUSAL
            and (not found or _fails(max(found, key=lambda f: f.score), opt))
            and (wall is None or wall.share < opt.frame_yaw_wall_share)):
        # The best placement would be refused: search again with each frame's yaw error, as
        # its own walls tell it, taken out (the per-frame yaw noise can blur the rigid scan so
        # much that the truth is no peak of the search).
        t0 = time.perf_counter()
        scan = _turned(scan, _frame_yaws(scan, opt))
        timings["frame_yaw"] = time.perf_counter() - t0
        found, storeys = _search_all(scan, sections, plan, storey_maps, opt, rng, timings,
                                     maps_cache)
        turned = True
    # 5. ranking, distinct hypotheses, ambiguity.
    found.sort(key=lambda f: -f.score)
    ranked: list[_Found] = []
    for f in found:
        if all(_distinct(f, r, opt) for r in ranked):
            ranked.append(f)
    hyps = []
    for f in ranked[:opt.report_top]:
        m = _transform(f, gravity, scan.floor_z)
        yaw = float(np.rad2deg(np.arctan2(m[1, 0], m[0, 0])))
        hyps.append(AlignHypothesis(matrix_to_pose(m), f.storey.floor_z, yaw, f.score, f.fit,
                                    f.rigid_fit, f.inliers, f.free, f.coarse, f.see_through,
                                    f.constraint, f.agreement))
    timings["total"] = time.perf_counter() - t_start
    if not ranked:
        raise GlobalAlignmentError(
            "global alignment found no placement of the trajectory in the BIM (too few wall "
            "or column points, or an empty floor plan)")
    best = ranked[0]
    ratio = ranked[1].score / best.score if len(ranked) > 1 and best.score > 0 else 0.0
    twins = twin_storeys(best.corr.apply(scan.xy), best.storey, sections, plan,
                         near_m=opt.inlier_m)
    twin_floors = [float(sections[j].floor_z) for j in twins if sections[j].floor_z is not None]
    t0 = time.perf_counter()
    alias = (_plan_alias(best, scan, sections, plan, storey_maps, opt, rng)
             if opt.alias_check else None)
    timings["alias"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    aliased = alias is not None and _alias_ambiguous(alias, opt)
    ambiguous = ratio >= opt.ambiguity_ratio or bool(twins) or aliased
    m_best = _transform(best, gravity, scan.floor_z)
    result = GlobalAlignResult(
        poses=matrix_to_pose(m_best @ pose_to_matrix(poses)),
        world_from_slam=hyps[0].world_from_slam,
        hypotheses=hyps, ambiguous=ambiguous, ratio=float(ratio),
        accepted_ambiguous=ambiguous and opt.accept_ambiguous, gravity_tilt_deg=tilt,
        gravity_applied=applied, storeys=storeys, timings=timings, options=opt,
        twin_floors=twin_floors, alias=alias, frames_turned=turned,
        seen_through_wall=None if turned else wall)
    fits = _fits(best, opt)
    if (fits and best.see_through > opt.max_see_through and not ambiguous
            and opt.see_through_window_frames > 0):
        # Refused for its see-through alone: measured again with each window of frames
        # polished (a drifted trajectory's walk), the ranking and every other test unchanged.
        t0 = time.perf_counter()
        result.drift_see_through = _drift_see_through(ranked, scan, plan, storey_maps, alias,
                                                      opt)
        timings["drift_see_through"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_start
    drift_ok = result.drift_see_through is not None and result.drift_see_through.accepted
    if (not fits and best.free >= opt.min_free_fraction
            and best.see_through <= opt.max_see_through and not ambiguous
            and opt.fit_trim_frames > 0):
        # Refused for its fit alone: measured again on the frames whose walls exist (a wall
        # missing or shifted as built), taken only when nothing else comes near.
        t0 = time.perf_counter()
        result.trimmed_fit = _trimmed_fit(best, scan, storey_maps[_section_key(plan, best.storey)],
                                          ratio, opt)
        timings["trimmed_fit"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_start
        fits = result.trimmed_fit.accepted
    if turned and opt.frame_yaw is FrameYaw.ON_REFUSAL and ratio > opt.frame_yaw_max_ratio:
        raise GlobalAlignmentError(
            f"global alignment: the best placement on the scan as given was refused, and on the "
            f"scan with each frame's yaw error taken out the second-best scores {ratio:.0%} of "
            f"the best (a placement found on a second try is taken at most at "
            f"{opt.frame_yaw_max_ratio:.0%}); is this the right BIM?\n" + result.describe(),
            result)
    if not fits or (best.see_through > opt.max_see_through and not drift_ok):
        raise GlobalAlignmentError(
            f"global alignment: the best placement fits badly (fit score {best.fit:.2f}, "
            f"minimum {opt.min_score}; cameras in free space {best.free:.0%}, minimum "
            f"{opt.min_free_fraction:.0%}; points seen through walls {best.see_through:.0%}, "
            f"maximum {opt.max_see_through:.0%}); is this the right BIM?\n"
            + result.describe(), result)
    if ambiguous and not opt.accept_ambiguous:
        if twins:
            why = (f"the storey has {len(twin_floors)} identical twin(s) (floors at "
                   f"{', '.join(f'{z:.2f}' for z in twin_floors)} m) that no scan can tell apart")
        elif aliased and alias is not None and (alias.score_ratio > ratio
                                                 or ratio < opt.ambiguity_ratio):
            exact = alias.score_ratio < opt.ambiguity_ratio
            why = (f"the plan repeats what the scan saw {alias.moved_m:.1f} m away, turned by "
                   f"{alias.yaw_deg:.0f} deg (ideal difference {alias.difference:.2f}), and the "
                   f"scan placed there scores {alias.score_ratio:.0%} of the best ("
                   + (f"the plan repeats within {opt.alias_exact_difference:.2f}, so no ratio "
                      f"tells them apart, and the scan fits there too: fit "
                      f"{alias.fit_score:.2f}, free {alias.scan_free_fraction:.0%}" if exact
                      else f"threshold {opt.ambiguity_ratio:.0%}")
                   + ("" if alias.vote is None else
                      f"; the rays where the plan differs voted {alias.vote.for_best} for the "
                      f"best, {alias.vote.for_alias} for the alias, from {alias.vote.frames} "
                      f"frames: too few or too even to decide")
                   + "; a point-symmetric or repeated layout)")
        else:
            why = (f"the second-best placement scores {ratio:.0%} of the best (threshold "
                   f"{opt.ambiguity_ratio:.0%}; a symmetric layout or repeated rooms)")
        raise AmbiguousAlignmentError(
            f"global alignment is ambiguous: {why}. Refusing to guess; accept the best with "
            "--accept-ambiguous (global_align.accept_ambiguous), or give an initial "
            "trajectory in the BIM frame.\n" + result.describe(), result)
    return result


def initial_free_fraction(world_from_cam: ArrayLike, plan: FloorPlan,
                          options: GlobalAlignOptions | None = None) -> float:
    """Fraction of the initial camera positions that lie in the building's free space: on a
    storey whose floor is 0.3-3 m below the camera, inside its plan section and clear of its
    walls (:func:`free_space_fraction`). Near 0 for a trajectory in a SLAM system's own frame,
    near 1 for one already in the BIM frame."""
    opt = GlobalAlignOptions() if options is None else options
    poses = np.asarray(world_from_cam, dtype=np.float64).reshape(-1, 7)
    free = np.zeros(len(poses), dtype=bool)
    for storey in _storeys(plan, opt.plan_cut_height_m):
        if storey.floor_z is None:
            on = np.ones(len(poses), dtype=bool)
        else:
            above = poses[:, 2] - storey.floor_z
            on = (above > 0.3) & (above < 3.0)
        if not on.any():
            continue
        _, ok = free_space_fraction(poses[on, :2], plan.segments[storey.rows],
                                    clearance_m=opt.free_clearance_m, n_rays=opt.enclosed_rays,
                                    min_hits=opt.enclosed_min_hits,
                                    shell=None if storey.shell is None
                                    else plan.segments[storey.shell])
        free[np.flatnonzero(on)[ok]] = True
    return float(free.mean()) if len(free) else 0.0
