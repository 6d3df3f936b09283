"""bimcap.io.png: 8-bit PNGs read without OpenCV's decoder, against cv2.imread (libpng).

The files are written here byte by byte (each of the PNG specification's five row filters, and
a mix), and by OpenCV's encoder at several compression levels and strategies; OpenCV's decoder,
which nobody here wrote, is the oracle. Everything outside the common case (palette, 16-bit,
alpha, interlaced, transparency, a damaged file) must come back as None so that the caller
reads it with OpenCV as before.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from bimcap.io.png import PNG_SIGNATURE, read_png


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    a, b, c = a.astype(np.int32), b.astype(np.int32), c.astype(np.int32)
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def _filtered(image: np.ndarray, filters: list[int]) -> bytes:
    """The IDAT stream's rows: each row filtered with its type, straight from the spec."""
    h = image.shape[0]
    rows = image.reshape(h, -1).astype(np.int32)
    bpp = 1 if image.ndim == 2 else image.shape[2]
    out = bytearray()
    for r in range(h):
        x = rows[r]
        b = rows[r - 1] if r else np.zeros_like(x)
        a = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        c = np.concatenate([np.zeros(bpp, np.int32), b[:-bpp]])
        ftype = filters[r % len(filters)]
        pred = [np.zeros_like(x), a, b, (a + b) // 2, _paeth(a, b, c)][ftype]
        out.append(ftype)
        out += ((x - pred) % 256).astype(np.uint8).tobytes()
    return bytes(out)


def _png(image: np.ndarray, filters: list[int], *, colour: int | None = None, depth: int = 8,
         interlace: int = 0, extra: list[tuple[bytes, bytes]] = (), idat_parts: int = 3,
         stream: bytes | None = None) -> bytes:
    h, w = image.shape[:2]
    colour = (0 if image.ndim == 2 else 2) if colour is None else colour
    data = zlib.compress(_filtered(image, filters), 6) if stream is None else stream
    step = max(1, len(data) // idat_parts + 1)
    parts = [data[i:i + step] for i in range(0, len(data), step)]
    body = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, interlace))
    for kind, chunk_body in extra:
        body += _chunk(kind, chunk_body)
    body += b"".join(_chunk(b"IDAT", p) for p in parts)
    return PNG_SIGNATURE + body + _chunk(b"IEND", b"")


def _write(tmp_path: Path, name: str, data: bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def _opencv(path: Path) -> np.ndarray | None:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is not None and img.ndim == 3:
        img = img[:, :, ::-1]
    return img


@pytest.mark.parametrize("filters", [[0], [1], [2], [3], [4], [4, 3, 2, 1, 0, 4, 1]])
@pytest.mark.parametrize("shape", [(17, 23, 3), (9, 1, 3), (1, 31, 3), (13, 29)])
def test_every_filter_as_opencv(tmp_path: Path, filters: list[int], shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(len(filters) * 100 + sum(shape))
    # smooth ramps and noise: every filter's predictor both right and wrong, Paeth's ties too
    ramp = (np.add.outer(np.arange(shape[0]) * 7, np.arange(shape[1]) * 3) % 256).astype(np.uint8)
    noise = rng.integers(0, 256, shape, dtype=np.uint8)
    image = ramp[..., None].repeat(3, axis=2) if len(shape) == 3 else ramp
    image = np.where(rng.random(shape) < 0.3, noise, image).astype(np.uint8)
    path = _write(tmp_path, "a.png", _png(image, filters))
    expected = _opencv(path)
    assert expected is not None
    np.testing.assert_array_equal(expected, image)  # the encoder above is right
    got = read_png(path)
    assert got is not None and got.dtype == np.uint8 and got.shape == image.shape
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("level", [0, 1, 6, 9])
@pytest.mark.parametrize("strategy", [cv2.IMWRITE_PNG_STRATEGY_DEFAULT,
                                      cv2.IMWRITE_PNG_STRATEGY_FILTERED,
                                      cv2.IMWRITE_PNG_STRATEGY_RLE])
def test_opencv_written_images(tmp_path: Path, level: int, strategy: int) -> None:
    rng = np.random.default_rng(level * 10 + strategy)
    yy, xx = np.mgrid[0:61, 0:87]
    bgr = np.stack([(xx * 3) % 256, (yy * 5) % 256, (xx + yy) % 256], 2).astype(np.uint8)
    bgr[rng.random(bgr.shape[:2]) < 0.1] = rng.integers(0, 256, 3, dtype=np.uint8)
    for name, img in (("rgb.png", bgr), ("grey.png", bgr[:, :, 1].copy())):
        p = tmp_path / name
        assert cv2.imwrite(str(p), img, [cv2.IMWRITE_PNG_COMPRESSION, level,
                                         cv2.IMWRITE_PNG_STRATEGY, strategy])
        got = read_png(p)
        assert got is not None
        np.testing.assert_array_equal(got, _opencv(p))


def _sequence(root: Path, n: int = 3):
    """A sequence written by bimcap's own writer (the simulator's): smooth ramps and noise."""
    from bimcap.dataset import SequenceWriter, read_sequence
    from bimcap.geometry import Camera

    h, w = 30, 41
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:h, 0:w]
    with SequenceWriter(root, Camera(w, h, 40.0, 40.0, 20.0, 15.0), np.array(
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])) as writer:
        for i in range(n):
            rgb = np.stack([(xx * 5 + i) % 256, (yy * 3) % 256, (xx * yy) % 256], 2)
            rgb = np.where(rng.random((h, w, 1)) < 0.2, rng.integers(0, 256, (h, w, 3)), rgb)
            labels = ((xx // 7 + yy // 5) % 5).astype(np.uint8)
            writer.add_frame(0.1 * i, rgb.astype(np.uint8), np.ones((5, 4), np.float32),
                             labels=labels)
    return read_sequence(root)


def test_written_frames_as_opencv(tmp_path: Path) -> None:
    """The images and labels bimcap's writer (the simulator's) puts on disk: every file read
    here, the same pixels as OpenCV's."""
    seq = _sequence(tmp_path / "seq")
    paths = [seq.root / f.image for f in seq.frames]
    paths += [seq.root / f.labels for f in seq.frames if f.labels is not None]
    assert len(paths) == 6
    for p in paths:
        got = read_png(p)
        assert got is not None, p
        np.testing.assert_array_equal(got, _opencv(p))


def _image() -> np.ndarray:
    return np.random.default_rng(3).integers(0, 256, (8, 12, 3), dtype=np.uint8)


@pytest.mark.parametrize("case", [
    "palette", "sixteen_bit", "rgba", "grey_alpha", "interlaced", "transparency", "gamma",
    "bad_crc", "truncated", "no_iend", "no_idat", "trailing_stream", "short_stream",
    "bad_filter", "not_png", "ihdr_not_first",
])
def test_falls_back_to_opencv(tmp_path: Path, case: str) -> None:
    """Anything but the common case is None (read with OpenCV then), never an exception or
    different pixels."""
    img = _image()
    grey = img[:, :, 0].copy()
    raw = _filtered(img, [1])
    if case == "palette":
        data = _png(grey, [0], colour=3, extra=[(b"PLTE", bytes(range(256)) * 3)])
    elif case == "sixteen_bit":
        _, enc = cv2.imencode(".png", grey.astype(np.uint16) * 257)
        data = enc.tobytes()
    elif case == "rgba":
        _, enc = cv2.imencode(".png", np.concatenate([img, img[:, :, :1]], 2))
        data = enc.tobytes()
    elif case == "grey_alpha":
        data = _png(np.stack([grey, grey], 2), [0], colour=4)
    elif case == "interlaced":
        data = _png(img, [0], interlace=1)
    elif case == "transparency":
        data = _png(img, [0], extra=[(b"tRNS", b"\x00\x01\x00\x02\x00\x03")])
    elif case == "gamma":
        data = _png(img, [0], extra=[(b"gAMA", struct.pack(">I", 45455))])
    elif case == "bad_crc":
        data = bytearray(_png(img, [1]))
        data[-20] ^= 0xFF  # inside the last IDAT chunk's body
        data = bytes(data)
    elif case == "truncated":
        data = _png(img, [1])[:-30]
    elif case == "no_iend":
        data = _png(img, [1])[:-12]
    elif case == "no_idat":
        data = PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", 12, 8, 8, 2, 0, 0, 0))
        data += _chunk(b"IEND", b"")
    elif case == "trailing_stream":
        data = _png(img, [1], stream=zlib.compress(raw + b"\x00" * 5))
    elif case == "short_stream":
        data = _png(img, [1], stream=zlib.compress(raw[:-3]))
    elif case == "bad_filter":
        data = _png(img, [1], stream=zlib.compress(b"\x05" + raw[1:]))
    elif case == "not_png":
        _, jpeg = cv2.imencode(".jpg", img)
        data = jpeg.tobytes()
    else:  # ihdr_not_first
        data = _png(img, [1])
        ihdr = data[8:8 + 25]
        data = PNG_SIGNATURE + _chunk(b"tEXt", b"a\x00b") + ihdr + data[8 + 25:]
    path = _write(tmp_path, "x.png", data)
    assert read_png(path) is None
    if case in ("palette", "sixteen_bit", "rgba", "grey_alpha", "transparency", "gamma"):
        assert cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is not None  # a file OpenCV reads


def test_neutral_chunks_are_read(tmp_path: Path) -> None:
    img = _image()
    data = _png(img, [4], extra=[(b"tEXt", b"Software\x00bimcap"),
                                 (b"pHYs", struct.pack(">IIB", 2835, 2835, 1))])
    got = read_png(_write(tmp_path, "x.png", data))
    assert got is not None
    np.testing.assert_array_equal(got, img)


def test_missing_file_raises(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_png(tmp_path / "absent.png")


def test_sequence_reads_a_damaged_png_as_before(tmp_path: Path) -> None:
    """Sequence.load_image: a PNG this module refuses goes to OpenCV, whose verdict stands (a
    damaged IDAT: "cannot decode image" naming the file and the field), and an image with a
    gamma chunk, which it reads, gives the same pixels as before."""
    from bimcap.dataset.sequence import SequenceError

    seq = _sequence(tmp_path / "seq", 2)
    path = seq.root / seq.frames[1].image
    before = seq.load_image(1)
    np.testing.assert_array_equal(before, _opencv(path))
    # a gAMA chunk sends the file to OpenCV's path (IMREAD_UNCHANGED applies no gamma)
    data = path.read_bytes()
    path.write_bytes(data[:33] + _chunk(b"gAMA", struct.pack(">I", 45455)) + data[33:])
    assert read_png(path) is None
    np.testing.assert_array_equal(seq.load_image(1), before)
    broken = bytearray(data)
    broken[60] ^= 0xFF
    path.write_bytes(bytes(broken))
    with pytest.raises(SequenceError, match=r"cannot decode image") as err:
        seq.load_image(1)
    assert str(path) in str(err.value) and "frames[1].image" in str(err.value)
