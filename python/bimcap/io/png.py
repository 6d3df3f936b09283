"""8-bit PNG images read in one compiled call: libdeflate's inflate and the PNG filters.

The front end reads one RGB image a frame. ``cv2.imread`` (libpng and zlib inside OpenCV's
wheel) took ~4.4 ms for a 516×386 simulator image, the channel swap to R, G, B included; here
the chunks are checked in Python (their CRCs with ``zlib.crc32``), and the IDAT stream is
inflated by libdeflate and the five filters of the PNG specification undone in one compiled
call (``bimcap/raster/png_rows.h``, ~2 ms), the channels left in the file's order (R, G, B).
PNG is lossless, so the pixels are libpng's bit for bit (``tests/test_io_png.py`` checks every
filter type against ``cv2.imread``).

Only the common case is read here: 8-bit grey or RGB, not interlaced, no chunk that could change
the pixels (a palette, transparency, gamma, colour profiles: only ``tEXt``, ``zTXt``, ``iTXt``,
``pHYs`` and ``tIME`` besides the critical ones). :func:`read_png` returns None for anything
else, and for a file it cannot vouch for (a bad signature, chunk CRC, zlib stream or size), so
that the caller reads it with ``cv2.imread`` as before and keeps its behaviour and its errors.
"""

from __future__ import annotations

import struct
import zlib
from os import PathLike

import numpy as np
from numpy.typing import NDArray

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: Ancillary chunks that do not change the decoded pixels (metadata, physical pixel size).
_NEUTRAL_CHUNKS = frozenset({b"tEXt", b"zTXt", b"iTXt", b"pHYs", b"tIME"})

#: Channels of the colour types read here (0: grey, 2: RGB).
_CHANNELS = {0: 1, 2: 3}

#: The largest inflated image read here (bytes); larger ones go to OpenCV.
MAX_INFLATED_BYTES = 1 << 30


def read_png(path: str | PathLike[str]) -> NDArray[np.uint8] | None:
    """The pixels of the 8-bit grey or RGB PNG file at ``path``, or None.

    Returns
    -------
    (H, W) uint8 for grey, (H, W, 3) uint8 for RGB in the file's channel order (R, G, B; not
    OpenCV's B, G, R); None when the file is not such a PNG (another format, bit depth or
    colour type, interlaced, a chunk that could change the pixels) or is damaged (signature,
    chunk lengths or CRCs, zlib stream, size): read it with ``cv2.imread`` then.

    Raises
    ------
    OSError: the file cannot be opened or read.
    """
    with open(path, "rb") as f:
        if f.read(8) != PNG_SIGNATURE:
            return None
        data = f.read()
    return _decode(memoryview(data))


def _decode(data: memoryview) -> NDArray[np.uint8] | None:
    """The pixels of a PNG file's bytes after its signature, or None (module docstring)."""
    from bimcap import _core

    header: tuple[int, ...] | None = None
    idat: list[memoryview] = []
    pos, end, ended = 0, len(data), False
    while pos + 12 <= end:
        (length,) = struct.unpack_from(">I", data, pos)
        kind = bytes(data[pos + 4:pos + 8])
        stop = pos + 8 + length
        if length > 0x7FFFFFFF or stop + 4 > end:
            return None
        (crc,) = struct.unpack_from(">I", data, stop)
        if zlib.crc32(data[pos + 4:stop]) != crc:
            return None
        body = data[pos + 8:stop]
        pos = stop + 4
        if header is None:  # IHDR must come first
            if kind != b"IHDR" or length != 13:
                return None
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            ended = True
            break
        elif kind not in _NEUTRAL_CHUNKS:
            return None
    if header is None or not ended or not idat:
        return None
    width, height, depth, colour, compression, filtering, interlace = header
    channels = _CHANNELS.get(colour)
    if (channels is None or depth != 8 or compression or filtering or interlace
            or not 0 < width < 1 << 31 or not 0 < height < 1 << 31):
        return None
    row_bytes = width * channels
    size = height * (row_bytes + 1)
    if size > MAX_INFLATED_BYTES:
        return None
    stream = np.frombuffer(b"".join(idat), np.uint8)
    try:
        rows = _core.decode_png_rows(stream, height, row_bytes, channels)
    except _core.InputError:  # not one zlib stream of the image's size, a filter type above 4
        return None
    image: NDArray[np.uint8] = rows if channels == 1 else rows.reshape(height, width, channels)
    return image
