// The scanlines of a PNG image from its inflated IDAT stream (PNG specification, 2nd edition,
// section 9 "Filtering"): each row is one filter-type byte and `row_bytes` filtered bytes,
// and each byte x is restored from its left neighbour a (the same channel one pixel, `bpp`
// bytes, back; 0 in the first pixel), the byte above b (0 in the first row) and the byte above
// the left neighbour c, modulo 256:
//
//   0 None     x
//   1 Sub      x + a
//   2 Up       x + b
//   3 Average  x + floor((a + b) / 2)
//   4 Paeth    x + the one of a, b, c nearest to p = a + b − c (ties: a, then b)
//
// The stream itself is inflated by libdeflate (zlib format, its Adler-32 checked), ~2× faster
// than zlib's inflate. Lossless: the result is the image any conforming decoder (libpng inside
// cv2.imread) gives.
#ifndef BIMCAP_RASTER_PNG_ROWS_H_
#define BIMCAP_RASTER_PNG_ROWS_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"

namespace bimcap::raster {

// out[r · row_bytes + i] for r < rows, i < row_bytes from `filtered` (rows · (1 + row_bytes)
// bytes). `bpp`: bytes a pixel (1 … 8). Throws RasterError ("filtered", nothing promised in
// `out`) for a filter type above 4, naming the row; ("bpp") for bpp outside [1, 8].
void UnfilterPngRows(const uint8_t* filtered, int64_t rows, int64_t row_bytes, int bpp,
                     uint8_t* out);

// The image's rows, as UnfilterPngRows, from the zlib stream of its IDAT chunks (`stream`,
// `stream_bytes` bytes, the chunks' data joined). Throws RasterError ("stream") when the
// stream is not one valid zlib stream inflating to exactly rows · (1 + row_bytes) bytes (bad
// data, a wrong checksum, too little or too much data, bytes after its end), and as
// UnfilterPngRows; ("rows") for rows or row_bytes below 1.
void DecodePngRows(const uint8_t* stream, int64_t stream_bytes, int64_t rows, int64_t row_bytes,
                   int bpp, uint8_t* out);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PNG_ROWS_H_
