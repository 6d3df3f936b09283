#include "bimcap/raster/png_rows.h"

#include <libdeflate.h>

#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

namespace bimcap::raster {

namespace {

inline uint8_t Paeth(int a, int b, int c) {
  const int p = a + b - c;
  const int pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
  if (pa <= pb && pa <= pc) return static_cast<uint8_t>(a);
  return static_cast<uint8_t>(pb <= pc ? b : c);
}

}  // namespace

void UnfilterPngRows(const uint8_t* filtered, int64_t rows, int64_t row_bytes, int bpp,
                     uint8_t* out) {
  if (bpp < 1 || bpp > 8) {
    throw RasterError("bpp", "must be in [1, 8], got " + std::to_string(bpp));
  }
  const int64_t left = bpp < row_bytes ? bpp : row_bytes;  // the bytes without a left neighbour
  for (int64_t r = 0; r < rows; ++r) {
    const uint8_t* in = filtered + r * (row_bytes + 1);
    const uint8_t type = in[0];
    ++in;
    uint8_t* cur = out + r * row_bytes;
    const uint8_t* up = r > 0 ? cur - row_bytes : nullptr;  // null: the row above is all 0
    switch (type) {
      case 0:
        for (int64_t i = 0; i < row_bytes; ++i) cur[i] = in[i];
        break;
      case 1:
        for (int64_t i = 0; i < left; ++i) cur[i] = in[i];
        for (int64_t i = left; i < row_bytes; ++i) {
          cur[i] = static_cast<uint8_t>(in[i] + cur[i - bpp]);
        }
        break;
      case 2:
        if (up == nullptr) {
          for (int64_t i = 0; i < row_bytes; ++i) cur[i] = in[i];
        } else {
          for (int64_t i = 0; i < row_bytes; ++i) cur[i] = static_cast<uint8_t>(in[i] + up[i]);
        }
        break;
      case 3:
        if (up == nullptr) {
          for (int64_t i = 0; i < left; ++i) cur[i] = in[i];
          for (int64_t i = left; i < row_bytes; ++i) {
            cur[i] = static_cast<uint8_t>(in[i] + (cur[i - bpp] >> 1));
          }
        } else {
          for (int64_t i = 0; i < left; ++i) cur[i] = static_cast<uint8_t>(in[i] + (up[i] >> 1));
          for (int64_t i = left; i < row_bytes; ++i) {
            cur[i] = static_cast<uint8_t>(in[i] + ((cur[i - bpp] + up[i]) >> 1));
          }
        }
        break;
      case 4:
        if (up == nullptr) {  // b = c = 0: Paeth picks a, as Sub
          for (int64_t i = 0; i < left; ++i) cur[i] = in[i];
          for (int64_t i = left; i < row_bytes; ++i) {
            cur[i] = static_cast<uint8_t>(in[i] + cur[i - bpp]);
          }
        } else {  // a = c = 0 in the first pixel: Paeth picks b, as Up
          for (int64_t i = 0; i < left; ++i) cur[i] = static_cast<uint8_t>(in[i] + up[i]);
          for (int64_t i = left; i < row_bytes; ++i) {
            cur[i] = static_cast<uint8_t>(in[i] + Paeth(cur[i - bpp], up[i], up[i - bpp]));
          }
        }
        break;
      default:
        throw RasterError("filtered", "row " + std::to_string(r) + " has filter type " +
                                          std::to_string(type) + " (PNG knows 0-4)");
    }
  }
}

void DecodePngRows(const uint8_t* stream, int64_t stream_bytes, int64_t rows, int64_t row_bytes,
                   int bpp, uint8_t* out) {
  if (rows < 1 || row_bytes < 1) {
    throw RasterError("rows", "rows and row_bytes must be >= 1, got " + std::to_string(rows) +
                                  " and " + std::to_string(row_bytes));
  }
  if (bpp < 1 || bpp > 8) {
    throw RasterError("bpp", "must be in [1, 8], got " + std::to_string(bpp));
  }
  const size_t size = static_cast<size_t>(rows) * static_cast<size_t>(row_bytes + 1);
  std::vector<uint8_t> filtered(size);
  const std::unique_ptr<libdeflate_decompressor, decltype(&libdeflate_free_decompressor)> inflater(
      libdeflate_alloc_decompressor(), &libdeflate_free_decompressor);
  if (!inflater) throw std::bad_alloc();
  size_t used = 0, produced = 0;
  const libdeflate_result result =
      libdeflate_zlib_decompress_ex(inflater.get(), stream, static_cast<size_t>(stream_bytes),
                                    filtered.data(), size, &used, &produced);
  if (result != LIBDEFLATE_SUCCESS) {
    throw RasterError("stream",
                      result == LIBDEFLATE_INSUFFICIENT_SPACE
                          ? "inflates to more than the image's " + std::to_string(size) + " bytes"
                          : "is not a valid zlib stream");
  }
  if (produced != size) {
    throw RasterError("stream", "inflates to " + std::to_string(produced) +
                                    " bytes, the image needs " + std::to_string(size));
  }
  if (used != static_cast<size_t>(stream_bytes)) {
    throw RasterError("stream", std::to_string(static_cast<size_t>(stream_bytes) - used) +
                                    " bytes after the end of the zlib stream");
  }
  UnfilterPngRows(filtered.data(), rows, row_bytes, bpp, out);
}

}  // namespace bimcap::raster
