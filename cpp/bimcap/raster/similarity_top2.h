// The descriptor matcher's reductions of one table of similarities
// (bimcap.features.matching._match_numpy past its integer products): per row the first index of
// its largest value, the largest and the second largest; per column the largest and the second
// largest; in one pass over the table instead of numpy's four or five.
//
// Second largest is counted with multiplicity, as numpy's "set the arg-max to −1, take the max
// again" is: where two entries reach the largest, the second largest equals it. The values are
// int32 (exact integer products); nothing is rounded.
#ifndef BIMCAP_RASTER_SIMILARITY_TOP2_H_
#define BIMCAP_RASTER_SIMILARITY_TOP2_H_

#include <cstdint>

namespace bimcap::raster {

// `sim` is a row-major (rows, cols) table, rows >= 1 and cols >= 2. Writes, per row i,
// row_best[i] (the first column of the row's largest value), row_s1[i], row_s2[i]; per column j,
// col_s1[j] and col_s2[j] (INT32_MIN where rows == 1).
void SimilarityTop2(const int32_t* sim, int64_t rows, int64_t cols, int64_t* row_best,
                    int32_t* row_s1, int32_t* row_s2, int32_t* col_s1, int32_t* col_s2);

}  // namespace bimcap::raster

#endif  // BIMCAP_RASTER_SIMILARITY_TOP2_H_
