"""Descriptor matching and geometric verification between two undistorted images.

Descriptor matching reimplements COLMAP's SIFT brute-force criteria in numpy (one matrix
product: ONNX Runtime's integer ``MatMulInteger`` of the uint8 descriptors, or BLAS in float32;
both exact, :class:`DescriptorProduct`): the distance of two RootSIFT descriptors is the angle
``acos(a·b / 512²)``; a match needs ``best < max_distance`` and ``best < max_ratio · second
best`` (Lowe's ratio test), in both directions when ``cross_check``. It exists because pycolmap
4.2's CPU brute-force matcher took ~13 s for one 9.6k × 9.6k pair on this machine against ~0.2 s
here; a test checks that both give the same matches (``MatcherBackend.PYCOLMAP`` keeps the
original as an oracle and an option). The integer products, with the rows' and columns' top two
taken in one pass in ``bimcap._core`` (``similarity_top2``), make a pair ~2× cheaper than BLAS's
at 1032 × 772 (docs/speed.md, "Matching in integers").

Binary descriptors (ORB's 32 bytes, :attr:`bimcap.features.SiftBackend.ORB`) are told apart by
their width and matched by Hamming distance in the same way: with the bits as ±1 the product of
two descriptors is ``256 − 2 · Hamming``, so one BLAS product gives both directions' two nearest
neighbours (36 ms a pair at ~1,600 keypoints against 135 ms for OpenCV's
``BFMatcher(NORM_HAMMING)`` asked both ways; a test checks both give the same matches). The
ratio test is on distances in bits; ``max_hamming`` takes the place of ``max_distance``.

Geometric verification keeps the RANSAC inliers of COLMAP's two-view geometry
(``pycolmap.estimate_calibrated_two_view_geometry``: essential / fundamental / homography model
selection with known intrinsics), or of a fundamental matrix alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.features.sift import ORB_DESCRIPTOR_BYTES, FeatureError, Features
from bimcap.geometry.camera import Camera

I32 = NDArray[np.int32]

#: Norm² of COLMAP's uint8 RootSIFT descriptors (unit vectors scaled by 512).
_DESC_NORM2 = 512.0 * 512.0

#: The most similarities the matcher holds at once (a block of rows of a by all of b; 64 MB):
#: two images of up to 4,096 keypoints are one block.
_BLOCK_ELEMENTS = 1 << 24


class MatcherBackend(str, Enum):
    """Who computes the putative descriptor matches."""

    NUMPY = "numpy"
    PYCOLMAP = "pycolmap"


class DescriptorProduct(str, Enum):
    """How the numpy matcher multiplies two sets of SIFT descriptors (the same integers).

    ``INT8``: ONNX Runtime's ``MatMulInteger`` (uint8 × int8 → int32, VNNI or ``vpmaddubsw``
    kernels) of the descriptors' low 7 bits, plus the few products of their high bit in BLAS;
    ~3.5× cheaper than ``FLOAT32`` on one core. ``FLOAT32``: one BLAS ``sgemm`` of the
    descriptors as float32. Both are exact, so they give the same matches bit for bit.
    """

    INT8 = "int8"
    FLOAT32 = "float32"


class Verification(str, Enum):
    """Geometric verification of putative matches.

    ``TWO_VIEW``: COLMAP's calibrated two-view geometry (E, F or H, whichever explains the pair).
    ``FUNDAMENTAL``: inliers of a LO-RANSAC fundamental matrix. ``NONE``: keep putative matches.
    """

    TWO_VIEW = "two_view"
    FUNDAMENTAL = "fundamental"
    NONE = "none"


@dataclass(frozen=True)
class MatchOptions:
    """Settings of one pair's matching.

    Attributes
    ----------
    backend: descriptor matcher of SIFT descriptors (ORB's binary ones always use numpy).
    max_ratio: Lowe's ratio (best / second best angle) must be below this.
    max_distance: best descriptor angle in radians must be below this (SIFT).
    max_hamming: best Hamming distance in bits (of 256) must be at most this (ORB).
    cross_check: keep only mutual best matches.
    verification: geometric verification model.
    max_error_px: RANSAC inlier threshold in pixels.
    min_num_inliers: a pair with fewer verified matches yields no matches at all.
    seed: RANSAC seed (deterministic results).
    ransac_min_trials: the fewest RANSAC hypotheses of each model (COLMAP's ``min_num_trials``);
        None: pycolmap's (100 for ``TWO_VIEW``, 1000 for ``FUNDAMENTAL``). With the nearly
        all-inlier pairs of a walk the confidence test stops RANSAC long before, so this is
        its cost: 10 (default) makes ``TWO_VIEW`` ~2.3× cheaper a pair, with BIMCaP within
        0.0074 cm / 0.0021° of 100 trials on ten worlds × four runs (docs/speed.md, "Matching,
        verification" and "New defaults"; ``FUNDAMENTAL`` was not measured with it).
        ``ransac_min_trials = 100`` gives the previous default (pycolmap's, for ``TWO_VIEW``;
        1000 for ``FUNDAMENTAL``). Left out of :meth:`to_dict` when None, as the cache keys
        were before the option existed.
    sampson_refinement: ``TWO_VIEW`` only: COLMAP's ``use_sampson_refinement`` (after RANSAC,
        the essential / fundamental matrix refined on its inliers by their Sampson errors and the
        inliers taken again). False (the default since 2026-11-28) makes a pair ~1.3× cheaper to
        verify (gen-demo-s0, 65 pairs: 4.08 against 3.18 ms; 13 of 17,333 inliers and no model
        changed); on the hard setting alone it moved BIMCaP by at most 0.0015 cm / 0.0002°
        (docs/speed.md, "Cheaper defaults"). True is pycolmap's own (the default before) and stays
        out of :meth:`to_dict`, as before the option existed.
    product: how the numpy matcher multiplies SIFT descriptors (:class:`DescriptorProduct`;
        ORB's always in BLAS). Exact both ways, so the same matches; ``INT8`` (default) is
        left out of :meth:`to_dict` (the front end's cache key), as before the option existed.
    """

    backend: MatcherBackend = MatcherBackend.NUMPY
    max_ratio: float = 0.8
    max_distance: float = 0.7
    max_hamming: int = 64
    cross_check: bool = True
    verification: Verification = Verification.TWO_VIEW
    max_error_px: float = 2.0
    min_num_inliers: int = 15
    seed: int = 0
    ransac_min_trials: int | None = 10
    product: DescriptorProduct = DescriptorProduct.INT8
    sampson_refinement: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.max_ratio <= 1.0:
            raise FeatureError(f"max_ratio must be in (0, 1], got {self.max_ratio}")
        if self.max_distance <= 0.0:
            raise FeatureError(f"max_distance must be positive, got {self.max_distance}")
        if not 0 < self.max_hamming <= 8 * ORB_DESCRIPTOR_BYTES:
            raise FeatureError(f"max_hamming must be in (0, 256] bits, got {self.max_hamming}")
        if self.max_error_px <= 0.0:
            raise FeatureError(f"max_error_px must be positive, got {self.max_error_px}")
        if self.min_num_inliers < 0:
            raise FeatureError("min_num_inliers must be >= 0")
        if self.ransac_min_trials is not None and not 1 <= self.ransac_min_trials <= 10000:
            # pycolmap refuses more than its max_num_trials (10000 for the two-view geometry)
            raise FeatureError("ransac_min_trials must be in [1, 10000], got "
                               f"{self.ransac_min_trials}")

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["backend"] = self.backend.value
        d["verification"] = self.verification.value
        if self.product is DescriptorProduct.INT8:
            del d["product"]  # the same matches as before it existed: the same cache keys
        else:
            d["product"] = self.product.value
        if self.ransac_min_trials is None:
            del d["ransac_min_trials"]
        if self.sampson_refinement:
            del d["sampson_refinement"]  # pycolmap's own, as before the option: the same keys
        return d


@dataclass
class PairMatches:
    """Verified matches of one image pair.

    Attributes
    ----------
    frame_a, frame_b: frame indices, ``frame_a < frame_b``.
    idx: (M, 2) int32 keypoint indices ``[index in a, index in b]``.
    num_putative: descriptor matches before verification.
    model: the verified model's name (``"CALIBRATED"``, ``"PLANAR"``, ... or ``"none"``).
    """

    frame_a: int
    frame_b: int
    idx: I32
    num_putative: int
    model: str


def match_descriptors(
    desc_a: NDArray[np.uint8], desc_b: NDArray[np.uint8], options: MatchOptions | None = None
) -> I32:
    """Putative matches between two sets of uint8 RootSIFT descriptors, or of binary ORB ones.

    Parameters
    ----------
    desc_a: (Na, 128) uint8 RootSIFT, or (Na, 32) uint8 ORB (256 bits, packed).
    desc_b: (Nb, D) uint8, the same D as ``desc_a``.

    Returns
    -------
    (M, 2) int32 ``[index in a, index in b]``, sorted by the index in a.
    """
    opts = options or MatchOptions()
    for name, d in (("desc_a", desc_a), ("desc_b", desc_b)):
        if (d.ndim != 2 or d.shape[1] not in (128, ORB_DESCRIPTOR_BYTES)
                or d.dtype != np.uint8):
            raise FeatureError(f"{name} must be (N, 128) or (N, {ORB_DESCRIPTOR_BYTES}) uint8, "
                               f"got {d.shape} {d.dtype}")
    if desc_a.shape[1] != desc_b.shape[1]:
        raise FeatureError(f"desc_a and desc_b are of different kinds: {desc_a.shape[1]} and "
                           f"{desc_b.shape[1]} bytes (SIFT and ORB features mixed)")
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), np.int32)
    if opts.backend is MatcherBackend.PYCOLMAP and desc_a.shape[1] == 128:
        return _match_pycolmap(desc_a, desc_b, opts)
    return _match_numpy(desc_a, desc_b, opts)


def _top2(
    sim: NDArray[Any], low: Any = -np.inf,
) -> tuple[NDArray[np.int64], NDArray[Any], NDArray[Any]]:
    """Per row: index of the largest similarity, the largest and the second largest (``low``:
    a value below every similarity, −∞ for float32, −1 for the integer products)."""
    best = np.argmax(sim, axis=1)
    rows = np.arange(len(sim))
    s1 = sim[rows, best].copy()
    tmp = sim[rows, best]
    sim[rows, best] = low
    s2 = sim.max(axis=1)
    sim[rows, best] = tmp
    return best, s1, s2


def _passes(s1: NDArray[np.float32], s2: NDArray[np.float32], opts: MatchOptions,
            binary: bool = False) -> NDArray[np.bool_]:
    """COLMAP's criteria on similarities (dot / 512²): angle test and ratio test; ``binary``:
    on ±1 products (``256 − 2 · Hamming``): Hamming distance test and ratio test in bits."""
    if binary:
        h1 = (8 * ORB_DESCRIPTOR_BYTES - s1.astype(np.float64)) / 2.0
        h2 = (8 * ORB_DESCRIPTOR_BYTES - s2.astype(np.float64)) / 2.0
        return (h1 <= opts.max_hamming) & (h1 < opts.max_ratio * h2)
    d1 = np.arccos(np.minimum(s1.astype(np.float64), 1.0))
    d2 = np.arccos(np.minimum(s2.astype(np.float64), 1.0))
    return (d1 <= opts.max_distance) & (d1 < opts.max_ratio * d2)


def _as_float(desc: NDArray[np.uint8]) -> NDArray[np.float32]:
    """RootSIFT scaled to unit vectors, or ORB's 256 bits as ±1 (their products are exact)."""
    if desc.shape[1] == ORB_DESCRIPTOR_BYTES:
        return np.unpackbits(desc, axis=1).astype(np.float32) * np.float32(2.0) - np.float32(1.0)
    return desc.astype(np.float32) / np.float32(512.0)


#: ``MatMulInteger`` (opset 10) of a uint8 (n, 128) by an int8 (128, m) into int32 (n, m): the
#: serialized ONNX model, built with ``onnx.helper`` (``tests/test_frontend_speed.py`` checks it),
#: so that the matcher needs ONNX Runtime (a core dependency) and not the ``onnx`` package.
_MATMUL_INTEGER_ONNX = bytes.fromhex(
    "0807120662696d6361703a740a180a01610a0162120179220d4d61744d756c496e7465676572121364657363"
    "726970746f725f70726f64756374735a150a016112100a0e0802120a0a0312016e0a030880015a150a016212"
    "100a0e0803120a0a030880010a0312016d62150a017912100a0e0806120a0a0312016e0a0312016d42040a00"
    "100a"
)

#: This process's ONNX Runtime session of :data:`_MATMUL_INTEGER_ONNX` (one thread; ``run`` may
#: be called from several threads at once).
_SESSION: Any = None


def _int8_session() -> Any:
    global _SESSION
    if _SESSION is None:
        from bimcap.errors import require

        ort = require("onnxruntime", "onnxruntime", None, "the descriptor matcher's integer "
                      "products ([matching] product = \"int8\"; \"float32\" needs no ONNX Runtime)")
        so = ort.SessionOptions()
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        _SESSION = ort.InferenceSession(_MATMUL_INTEGER_ONNX, sess_options=so,
                                        providers=["CPUExecutionProvider"])
    return _SESSION


class _Int8Rows:
    """uint8 SIFT descriptors split for exact integer products: ``d = lo + 128 · hi`` with
    ``lo = d & 127`` and ``hi = d >> 7`` (0 or 1; a few rows have it), so that every operand
    of ``MatMulInteger`` is below 128: no two uint8 × int8 products summed in a kernel's 16-bit
    step (``vpmaddubsw`` without VNNI) can saturate (2 · 127 · 127 < 2¹⁵).

    Attributes
    ----------
    d: (n, 128) uint8, the descriptors.
    lo: (n, 128) uint8, the low 7 bits.
    lo_t: (128, n) int8, ``lo`` transposed (a right operand of ``MatMulInteger``).
    hi_rows: (k,) int64 rows with some value >= 128, or the slice of them when they are the
        last rows.
    hi: (k, 128) uint8, their high bits (0 or 1).
    hi_t: (128, k) int8, ``hi`` transposed.
    """

    def __init__(self, d: NDArray[np.uint8]) -> None:
        self.d = d
        self.lo = d & np.uint8(127)
        self.lo_t = np.ascontiguousarray(self.lo.T).view(np.int8)
        rows = np.flatnonzero((d >= 128).any(axis=1))
        first = len(d) - len(rows)
        self.hi_rows: slice | NDArray[np.int64] = (
            slice(first, len(d)) if np.array_equal(rows, np.arange(first, len(d))) else rows)
        self.hi = d[self.hi_rows] >> 7
        self.hi_t = np.ascontiguousarray(self.hi.T).view(np.int8)

    def rows(self, sel: slice | NDArray[np.int64]) -> _Int8Rows:
        """The rows ``sel`` (a slice or indices)."""
        return _Int8Rows(self.d[sel])

    @classmethod
    def high_bits_last(cls, d: NDArray[np.uint8]) -> tuple[NDArray[np.int64], _Int8Rows]:
        """(:func:`_hi_last`'s order of ``d``, ``_Int8Rows(d[order])``) in one compiled pass
        (bimcap/raster/descriptor_split.h: the same bytes; the rows with a high bit last)."""
        from bimcap import _core

        order, first, ordered, lo, lo_t, hi, hi_t = _core.split_descriptors(
            np.ascontiguousarray(d, dtype=np.uint8))
        rows = cls.__new__(cls)
        rows.d, rows.lo, rows.lo_t = ordered, lo, lo_t
        rows.hi_rows, rows.hi, rows.hi_t = slice(first, len(d)), hi, hi_t
        return order, rows


def _int8_products(x: _Int8Rows, y: _Int8Rows) -> NDArray[np.int32]:
    """(len(x), len(y)) int32 ``x · yᵀ`` of the uint8 descriptors, exactly, in ONNX Runtime's
    integer kernel: ``x · y = x_lo · y_lo + 128 · x_lo · y_hi + 128 · x_hi · y_lo
    + 128² · x_hi · y_hi``, the three last on the few rows and columns with a high bit (a slice
    of the output when they are the last rows: :func:`_hi_last`). Every sum is an integer below
    2²⁴ (128 · 255²)."""
    run = _int8_session().run
    sim = np.asarray(run(None, {"a": x.lo, "b": y.lo_t})[0], np.int32)
    if len(x.hi) and len(y.hi):
        hh = np.asarray(run(None, {"a": x.hi, "b": y.hi_t})[0], np.int32)
    if len(y.hi):
        sim[:, y.hi_rows] += 128 * np.asarray(run(None, {"a": x.lo, "b": y.hi_t})[0], np.int32)
    if len(x.hi):
        part = 128 * np.asarray(run(None, {"a": x.hi, "b": y.lo_t})[0], np.int32)
        if len(y.hi):
            part[:, y.hi_rows] += 16384 * hh
        sim[x.hi_rows] += part
    return sim


def _hi_last(d: NDArray[np.uint8]) -> NDArray[np.int64]:
    """(n,) int64 order of the rows of ``d``: those without a value >= 128, then those with one
    (each in its order)."""
    hi = (d >= 128).any(axis=1)
    return np.concatenate([np.flatnonzero(~hi), np.flatnonzero(hi)])


def _match_numpy(a: NDArray[np.uint8], b: NDArray[np.uint8], opts: MatchOptions) -> I32:
    """Mutual nearest neighbours with the ratio test in both directions, from one product.

    Every similarity is exact (uint8 products summed: an integer below 2²⁴, in int32 or float32,
    times 2⁻¹⁸ for SIFT; a sum of ±1 for ORB), so it is the same whatever the order of the sums
    or the kernel (:class:`DescriptorProduct`): a block of rows, its transpose or a subset of
    columns give the same numbers bit for bit. The b → a direction then needs no column-wise
    arg-max: row i's best column j is also j's best row exactly when ``sim[i, j]`` equals the
    column's maximum, and where two rows reach it the column's second best equals its best,
    which fails the ratio test (as before, when the first of the two rows was the arg-max). The
    column's second best is its maximum once the one candidate row is set to −∞ (−1 for the
    integer products, all >= 0). With the integer products in one block, ``_core``'s
    ``similarity_top2`` takes every row's and column's top two in one pass (a column's second
    best counted with multiplicity: the same value as "without its one candidate row").
    """
    binary = a.shape[1] == ORB_DESCRIPTOR_BYTES
    if binary or opts.product is DescriptorProduct.FLOAT32:
        fa, fb = _as_float(a), _as_float(b)

        def products(rows_a: slice | None, rows_b: NDArray[np.int64] | None = None
                     ) -> NDArray[Any]:
            """Rows ``rows_a`` of a by b, or (``rows_b`` given) rows ``rows_b`` of b by a."""
            if rows_b is not None:
                return fb[rows_b] @ fa.T
            return (fa if rows_a is None else fa[rows_a]) @ fb.T

        order_a = order_b = None
        low: Any = -np.inf
        dtype: Any = np.float32
        scale = np.float32(1.0)
    else:
        # Rows reordered so that those with a high bit come last (one slice of columns to
        # correct); the matches do not depend on the order of the rows: a row or column whose
        # two best are equal fails the ratio test whichever of them is first, and the index
        # pairs are mapped back and sorted at the end.
        (order_a, ia8), (order_b, ib8) = _Int8Rows.high_bits_last(a), _Int8Rows.high_bits_last(b)

        def products(rows_a: slice | None, rows_b: NDArray[np.int64] | None = None
                     ) -> NDArray[Any]:
            """Rows ``rows_a`` of a by b, or (``rows_b`` given) rows ``rows_b`` of b by a."""
            if rows_b is not None:
                return _int8_products(ib8.rows(rows_b), ia8)
            return _int8_products(ia8 if rows_a is None else ia8.rows(rows_a), ib8)

        low = -1
        dtype = np.int32
        scale = np.float32(1.0 / _DESC_NORM2)  # 2⁻¹⁸: exact on integers below 2²⁴
    chunk = max(2048, _BLOCK_ELEMENTS // max(len(b), 1))
    best_ab = np.empty(len(a), np.int64)
    s1_ab = np.empty(len(a), np.float32)
    ok_ab = np.empty(len(a), bool)
    col_s1: NDArray[Any] = np.full(len(b), low, dtype)
    sim: NDArray[Any] = np.zeros((0, len(b)), dtype)
    if 2 <= len(a) <= chunk and dtype is np.int32 and _core_top2():
        # one block of integer products: every reduction in one pass (bimcap._core)
        from bimcap import _core

        sim = products(None)
        best, s1i, s2i, c1i, c2i = _core.similarity_top2(sim)
        s1, s2 = s1i.astype(np.float32) * scale, s2i.astype(np.float32) * scale
        col_s1 = c1i.astype(np.float32) * scale
        ia = np.flatnonzero(_passes(s1, s2, opts, binary))
        ib = best[ia]
        if opts.cross_check:
            # the rows that are their column's best; where two rows are, the column's second
            # best equals its best and fails the ratio test (the column's top two count equal
            # values twice, as "the column without its one candidate row" does below)
            top = s1[ia] == col_s1[ib]
            ia, ib = ia[top], ib[top]
            keep = _passes(col_s1[ib], c2i[ib].astype(np.float32) * scale, opts, binary)
            ia, ib = ia[keep], ib[keep]
        return _original_order(ia, ib, order_a, order_b)
    for start in range(0, len(a), chunk):
        sim = products(slice(start, start + chunk) if len(a) > chunk else None)
        best, s1, s2 = _top2(sim, low)
        s1, s2 = s1.astype(np.float32) * scale, s2.astype(np.float32) * scale
        best_ab[start : start + len(sim)] = best
        s1_ab[start : start + len(sim)] = s1
        ok_ab[start : start + len(sim)] = _passes(s1, s2, opts, binary)
        np.maximum(col_s1, sim.max(axis=0), out=col_s1)
    col_s1 = col_s1.astype(np.float32) * scale
    ia = np.flatnonzero(ok_ab)
    ib = best_ab[ia]
    if opts.cross_check:
        # the rows that are their column's best, then those alone in their column
        top = s1_ab[ia] == col_s1[ib]
        ia, ib = ia[top], ib[top]
        alone = np.bincount(ib, minlength=len(b))[ib] == 1
        ia, ib = ia[alone], ib[alone]
        if len(a) <= chunk:  # the one block of rows is still there
            sim[ia, ib] = low
            col_s2 = sim.max(axis=0)[ib]
        else:  # the candidate columns again, as rows (the same numbers)
            col_s2 = np.empty(len(ib), dtype)
            for start in range(0, len(ib), chunk):
                part = products(None, ib[start : start + chunk])
                part[np.arange(len(part)), ia[start : start + chunk]] = low
                col_s2[start : start + len(part)] = part.max(axis=1)
        keep = _passes(col_s1[ib], col_s2.astype(np.float32) * scale, opts, binary)
        ia, ib = ia[keep], ib[keep]
    return _original_order(ia, ib, order_a, order_b)


def _original_order(ia: NDArray[np.int64], ib: NDArray[np.int64],
                    order_a: NDArray[np.int64] | None, order_b: NDArray[np.int64] | None) -> I32:
    """(M, 2) int32 matches ``[ia, ib]`` of reordered rows (``order_a``, ``order_b``: the
    original index of each; None: not reordered) as indices of the original rows, sorted by
    the index in a."""
    if order_a is not None and order_b is not None:
        ia, ib = order_a[ia], order_b[ib]
        by_a = np.argsort(ia, kind="stable")
        ia, ib = ia[by_a], ib[by_a]
    return np.stack([ia, ib], axis=1).astype(np.int32)


def _core_top2() -> bool:
    """Whether the compiled module has the one-pass reductions (a ``_core`` built before them
    has not: the matcher then reduces in numpy, with the same matches)."""
    try:
        from bimcap import _core
    except ImportError:  # pragma: no cover - the package is built with its module
        return False
    return hasattr(_core, "similarity_top2")


def _match_pycolmap(a: NDArray[np.uint8], b: NDArray[np.uint8], opts: MatchOptions) -> I32:
    import pycolmap

    pycolmap.logging.minloglevel = 2
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = 1
    mo.use_gpu = False
    mo.sift.max_ratio = opts.max_ratio
    mo.sift.max_distance = opts.max_distance
    mo.sift.cross_check = opts.cross_check
    matcher = pycolmap.FeatureMatcher.create(mo, pycolmap.Device.cpu)
    sift = pycolmap.FeatureExtractorType.SIFT
    da = pycolmap.FeatureDescriptors(sift, np.ascontiguousarray(a))
    db = pycolmap.FeatureDescriptors(sift, np.ascontiguousarray(b))
    m = np.asarray(matcher.match(pycolmap.FeatureKeypoints(), da, pycolmap.FeatureKeypoints(), db))
    m = m.astype(np.int32).reshape(-1, 2)
    return m[np.argsort(m[:, 0], kind="stable")]


def verify_matches(
    uv_a: NDArray[np.float64],
    uv_b: NDArray[np.float64],
    matches: I32,
    camera: Camera,
    options: MatchOptions | None = None,
) -> tuple[I32, str]:
    """Geometric verification of putative matches between two undistorted images.

    Parameters
    ----------
    uv_a, uv_b: (Na, 2), (Nb, 2) keypoint pixels of the undistorted (pinhole) images.
    matches: (M, 2) int32 putative matches.
    camera: the pinhole camera of both images (its distortion, if any, is ignored).

    Returns
    -------
    inliers: (M', 2) int32, a subset of ``matches`` (empty when fewer than ``min_num_inliers``).
    model: name of the verified model.

    Notes
    -----
    With ``TWO_VIEW``, COLMAP labels a pair ``PLANAR_OR_PANORAMIC`` when a homography explains
    most essential-matrix inliers (small baseline, or a mostly planar view) and then keeps the
    larger of the two inlier sets, usually the essential matrix's. Under (near) pure rotation the
    epipolar test is weak, so a few wrong matches can pass; the 3-D distance filter
    (:class:`bimcap.features.MatchFilterOptions`) removes those that have depth.
    """
    opts = options or MatchOptions()
    empty = np.zeros((0, 2), np.int32)
    if len(matches) == 0:
        return empty, "none"
    if opts.verification is Verification.NONE:
        return matches.astype(np.int32), "none"
    if len(matches) < max(opts.min_num_inliers, 8):
        return empty, "too_few"
    import pycolmap

    pycolmap.logging.minloglevel = 2
    pa = np.ascontiguousarray(uv_a[matches[:, 0]], dtype=np.float64)
    pb = np.ascontiguousarray(uv_b[matches[:, 1]], dtype=np.float64)
    if opts.verification is Verification.FUNDAMENTAL:
        ro = pycolmap.RANSACOptions()
        ro.max_error = opts.max_error_px
        ro.random_seed = opts.seed
        if opts.ransac_min_trials is not None:
            ro.min_num_trials = opts.ransac_min_trials
        res = pycolmap.estimate_fundamental_matrix(pa, pb, ro)
        if res is None:
            return empty, "degenerate"
        inl = matches[np.asarray(res["inlier_mask"], dtype=bool)]
        model = "FUNDAMENTAL"
    else:
        # Pixel origin does not matter here as long as both points and (cx, cy) use the same one.
        cam = pycolmap.Camera(
            model="PINHOLE",
            width=camera.width,
            height=camera.height,
            params=[camera.fx, camera.fy, camera.cx, camera.cy],
        )
        to = pycolmap.TwoViewGeometryOptions()
        to.ransac.max_error = opts.max_error_px
        to.ransac.random_seed = opts.seed
        if opts.ransac_min_trials is not None:
            to.ransac.min_num_trials = opts.ransac_min_trials
        to.min_num_inliers = opts.min_num_inliers
        to.use_sampson_refinement = opts.sampson_refinement
        # A rig that stands still gives matches at the same pixels; they are valid constraints,
        # not a watermark, so COLMAP's watermark detection is switched off.
        to.detect_watermark = False
        local = np.stack([np.arange(len(matches)), np.arange(len(matches))],
                         axis=1).astype(np.uint32)
        geom = pycolmap.estimate_calibrated_two_view_geometry(cam, pa, cam, pb, local, to)
        model = pycolmap.TwoViewGeometryConfiguration(int(geom.config)).name
        bad = {"UNDEFINED", "DEGENERATE", "WATERMARK"}
        if model in bad:
            return empty, model
        sel = np.asarray(geom.inlier_matches, dtype=np.int64).reshape(-1, 2)[:, 0]
        inl = matches[np.sort(sel)]
    if len(inl) < opts.min_num_inliers:
        return empty, model
    return inl.astype(np.int32), model


def match_pair(
    feats_a: Features,
    feats_b: Features,
    camera: Camera,
    frame_a: int,
    frame_b: int,
    options: MatchOptions | None = None,
) -> PairMatches:
    """Match and verify one image pair (``frame_a < frame_b``)."""
    opts = options or MatchOptions()
    putative = match_descriptors(feats_a.descriptors, feats_b.descriptors, opts)
    inl, model = verify_matches(feats_a.uv, feats_b.uv, putative, camera, opts)
    return PairMatches(frame_a, frame_b, inl, len(putative), model)


def sequential_pairs(num_frames: int, window: int) -> list[tuple[int, int]]:
    """All pairs ``(i, j)`` with ``0 < j − i <= window``, ordered by i then j."""
    if window < 1:
        raise FeatureError(f"window must be >= 1, got {window}")
    return [
        (i, j) for i in range(num_frames) for j in range(i + 1, min(num_frames, i + window + 1))
    ]
