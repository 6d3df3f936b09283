// The RANSAC score tables of the geometric segmenter (bimcap.segmentation.geometric._plane_scores)
// past their BLAS products, in numpy's arithmetic bit for bit.
//
// For a block of `rows` sample points i and `cols` plane hypotheses j (unit normal h_j, offset
// d_j), given the products t_ij = p_i · h_j and, when normals are checked, a_ij = n_i · h_j (both
// numpy's BLAS products, left there: their rounding is the library's):
//
//   ok_ij = |t_ij + d_j| < thr_i   and (a given)  |a_ij| > cos_n
//   score_j += Σ_i ok_ij
//
// One addition and two comparisons an entry, rounded as numpy's `dist += d`, `np.abs`, `<` and
// `>` are (a NaN fails both tests). The file is compiled with -ffp-contract=off like the rest of
// the library.
#ifndef BIMCAP_RASTER_PLANE_SCORES_H_
#define BIMCAP_RASTER_PLANE_SCORES_H_

#include <cstdint>

namespace bimcap::raster {

// Adds the block's counts to `score` (cols,). `products` and `agree` are row-major (rows, cols)
// tables (`agree` null: normals not checked), `offsets` (cols,) the d_j, `thresholds` (rows,) the
// thr_i in metres.
void AddPlaneScores(const double* products, const double* agree, const double* offsets,
                    const double* thresholds, int64_t rows, int64_t cols, double cos_n,
                    int64_t* score);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PLANE_SCORES_H_
