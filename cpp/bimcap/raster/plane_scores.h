// The RANSAC score tables of the geometric segmenter (bimcap.segmentation.geometric._plane_scores)
// and of the planar smoothing (bimcap.fusion.completion._inlier_counts), products included.
//
// For sample points p_i (with normals n_i when they are checked) and plane hypotheses j (unit
// normal h_j, offset d_j):
//
//   t_ij = fma(p_i2, h_j2, fma(p_i1, h_j1, p_i0 h_j0))      (a_ij the same with n_i)
//   ok_ij = |t_ij + d_j| < thr_i   and (normals given)  |a_ij| > cos_n
//   score_j += Σ_i ok_ij
//
// t_ij is rounded as OpenBLAS's matrix-matrix kernels form a 3-term product on CPUs with fused
// multiply-add (x86-64 since Haswell and Zen): numpy's `p @ h.T` with two rows or more and two
// columns or more (one row or one column goes to a matrix-vector kernel that rounds otherwise:
// the callers keep those in numpy), bit for bit (tests compare with numpy); the same numbers on
// a CPU without FMA (std::fma, correctly rounded in software there, slower). The sum, absolute
// values and comparisons are rounded as numpy's `dist += d`, `np.abs`, `<` and `>` (a NaN fails
// both tests). Computed without forming the (N, I) tables.
#ifndef BIMCAP_RASTER_PLANE_SCORES_H_
#define BIMCAP_RASTER_PLANE_SCORES_H_

#include <cstdint>

namespace bimcap::raster {

// Adds to `score` (hypotheses,) the counts of the `rows` points. `points` and `normals` are
// row-major (rows, 3) (`normals` null: not checked), `planes` (hypotheses, 3) unit normals,
// `offsets` (hypotheses,) the d_j, `thresholds` (rows,) the thr_i in metres.
void AddPlaneScores(const double* points, const double* normals, const double* planes,
                    const double* offsets, const double* thresholds, int64_t rows,
                    int64_t hypotheses, double cos_n, int64_t* score);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_PLANE_SCORES_H_
