// W and Co: wall / column points against the floor plan's segments of their class. Each point
// is associated with the nearest visible segment within the gate (association.h), re-associated
// between Ceres runs; residual: the xy distance of the world point to the segment's line (m,
// point_to_segment.h).
#include <cmath>
#include <string>

#include "bimcap/builder.h"
#include "bimcap/checks.h"
#include "bimcap/cost_functions/point_to_segment.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

// The floor plan, shared by every segment term.
void CheckSegments(const ProblemData& p) {
  const ArrayRef<double> segments = p.F64("segments");
  const ArrayRef<int32_t> segment_class = p.I32("segment_class");
  const ArrayRef<double> segment_z = p.F64("segment_z");
  const ArrayRef<double> segment_normal = p.F64("segment_normal");
  const int64_t s = segments.rows;
  CheckShape(segments, "segments", s, 4);
  CheckShape(segment_class, "segment_class", s, 1);
  CheckShape(segment_z, "segment_z", s, 2);
  CheckFinite(segments, "segments");
  CheckFinite(segment_z, "segment_z");
  for (int64_t i = 0; i < s; ++i) {
    const int32_t cls = segment_class(i);
    bool known = false;
    for (const TermSpec& term : Terms())
      known = known || (term.segment_class > 0 && cls == term.segment_class);
    if (!known) {
      throw ProblemError("segment_class", "row " + std::to_string(i) + ": class " +
                                              std::to_string(cls) +
                                              " is neither 1 (wall) nor 4 (column)");
    }
    if (segment_z(i, 0) > segment_z(i, 1)) {
      throw ProblemError("segment_z", "row " + std::to_string(i) + ": zmin > zmax");
    }
  }
  // Optional: absent (no visibility test) or one free-side normal per segment, unit or zero.
  if (!segment_normal.empty()) {
    CheckShape(segment_normal, "segment_normal", s, 2);
    CheckFinite(segment_normal, "segment_normal");
    for (int64_t i = 0; i < s; ++i) {
      const double norm = std::hypot(segment_normal(i, 0), segment_normal(i, 1));
      if (norm != 0.0 && std::abs(norm - 1.0) > 1e-6) {
        throw ProblemError("segment_normal", "row " + std::to_string(i) + " has norm " +
                                                 std::to_string(norm) + ", expected 1 or 0");
      }
    }
  }
}

void AddSegmentTerm(ProblemBuilder& builder, int term_id) {
  const TermSpec& spec = Terms()[term_id];
  const ProblemData& data = builder.data();
  const ArrayRef<int32_t> frame = data.I32(std::string(spec.points) + "_frame");
  const ArrayRef<double> p_in_cam = data.F64(std::string(spec.points) + "_p_in_cam");
  const std::vector<int>& association = builder.state().segment_of[term_id];
  if (static_cast<int64_t>(association.size()) != frame.rows) {  // not associated (yet)
    builder.blocks(term_id) = TermBlocks();
    builder.blocks(term_id).num_skipped = frame.rows;
    return;
  }
  int64_t count = 0;
  for (int s : association) count += s >= 0 ? 1 : 0;
  if (!builder.Prepare(term_id, count, builder.options().term(term_id).sigma, 1)) {
    builder.blocks(term_id).num_skipped = frame.rows - count;
    return;
  }
  TermBlocks& term = builder.blocks(term_id);
  term.num_skipped = frame.rows - count;
  const ArrayRef<double> segments = data.F64("segments");
  for (int64_t i = 0; i < frame.rows; ++i) {
    const int s = association[i];
    if (s < 0) continue;
    const double* seg = segments.row(s);
    builder.AddObservation(PointToSegmentCostFunction::Create(
                               Eigen::Vector3d(p_in_cam(i, 0), p_in_cam(i, 1), p_in_cam(i, 2)),
                               Eigen::Vector4d(seg[0], seg[1], seg[2], seg[3]), term.sqrt_weight),
                           {builder.Pose(frame(i))});
  }
  term.num_residual_blocks = count;
}

std::vector<ArraySpec> SegmentArrays(const char* frame, const char* p_in_cam) {
  return {{frame, DType::kInt32, 0},         {p_in_cam, DType::kFloat64, 3},
          {"segments", DType::kFloat64, 4},  {"segment_class", DType::kInt32, 0},
          {"segment_z", DType::kFloat64, 2}, {"segment_normal", DType::kFloat64, 2}};
}

}  // namespace

TermSpec WallTerm() {
  return TermSpec{"W",
                  "wall",
                  "wall",
                  "wall points to their wall segment, xy distance (m)",
                  /*paper_term=*/true,
                  /*bim_term=*/true,
                  TermOptions{true, 0.0007, 1.0, 0.05, LossType::kHuber, 1.0, {}},
                  SegmentArrays("wall_frame", "wall_p_in_cam"),
                  {},
                  /*segment_class=*/1,
                  /*facap_plane=*/false,
                  /*points=*/"wall",
                  [](const ProblemData& p) {
                    CheckPointsInCamera(p, "wall");
                    CheckSegments(p);
                  },
                  AddSegmentTerm};
}

TermSpec ColumnTerm() {
  return TermSpec{"Co",
                  "column",
                  "column",
                  "column points to their column segment, xy distance (m)",
                  /*paper_term=*/true,
                  /*bim_term=*/true,
                  TermOptions{true, 0.0007, 1.0, 0.05, LossType::kHuber, 1.0, {}},
                  SegmentArrays("column_frame", "column_p_in_cam"),
                  {},
                  /*segment_class=*/4,
                  /*facap_plane=*/false,
                  /*points=*/"column",
                  [](const ProblemData& p) {
                    CheckPointsInCamera(p, "column");
                    CheckSegments(p);
                  },
                  AddSegmentTerm};
}

}  // namespace bimcap
