// Depth from a triangle-id image and one affine function per triangle: the per-pixel half of
// the linear depth completion (bimcap.fusion.completion.complete_linear).
//
//   k = id(u, v),   f = ((c0[k] · u) + (c1[k] · v)) + c2[k]        (u column, v row, in double)
//   inverse depth:  out = f > 0 ? 1 / max(f, 1e-12) : 0
//   depth:          out = max(f, 0)         (np.maximum: a NaN f stays NaN, −0 becomes +0)
//   out rounded to float32 (to nearest).
//
// Every operation is rounded on its own, in numpy's order (`f = c0[id] * u; f += c1[id] * v;
// f += c2[id]`), so the result is numpy's bit for bit: the file is compiled with
// -ffp-contract=off (no fused multiply-add). Column 0 of the table is the "no triangle" entry
// (zeros: f = 0, out = 0).
#ifndef BIMCAP_RASTER_PIECEWISE_AFFINE_H_
#define BIMCAP_RASTER_PIECEWISE_AFFINE_H_

#include <cstdint>

#include "bimcap/raster/convex_fill.h"
#include "bimcap/raster/image.h"

namespace bimcap::raster {

// What the affine function interpolates.
enum class AffineValue {
  kInverseDepth,  // f = 1/z: out = 1/f where f > 0
  kDepth,         // f = z:   out = max(f, 0)
};

// out(v, u) from `ids` (same shape as `out`; every id in [0, count)) and `coef`, a row-major
// (3, count) table: coef[k] = c0[k], coef[count + k] = c1[k], coef[2 count + k] = c2[k].
// Throws RasterError ("tri_id") for an id outside [0, count) or images of different shapes;
// `out` may then be partly written.
void EvaluatePiecewiseAffine(const ImageRef<const int32_t>& ids, const double* coef, int64_t count,
                             AffineValue value, const ImageRef<float>& out);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PIECEWISE_AFFINE_H_
