// F and Ce: floor / ceiling points against planes. BIM plane mode: the fixed BIM plane of each
// point (`<term>_plane` indexes `planes`), residual n·(world_from_cam p) + d (m,
// point_to_plane.h). FACaP plane mode: one free plane per term, fitted to the term's points.
#include <cmath>
#include <string>

#include "bimcap/builder.h"
#include "bimcap/checks.h"
#include "bimcap/cost_functions/point_to_plane.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

void CheckPlanes(const ProblemData& p) {
  const ArrayRef<double> planes = p.F64("planes");
  CheckShape(planes, "planes", planes.rows, 4);
  CheckFinite(planes, "planes");
  for (int64_t i = 0; i < planes.rows; ++i) {
    const double* pl = planes.row(i);
    const double norm = std::sqrt(pl[0] * pl[0] + pl[1] * pl[1] + pl[2] * pl[2]);
    if (std::abs(norm - 1.0) > 1e-6) {
      throw ProblemError("planes", "plane " + std::to_string(i) + " has a normal of norm " +
                                       std::to_string(norm) + ", expected 1");
    }
  }
}

void CheckPlaneTerm(const ProblemData& p, const std::string& prefix) {
  CheckPlanes(p);
  CheckPointsInCamera(p, prefix);
  const ArrayRef<int32_t> plane = p.I32(prefix + "_plane");
  CheckShape(plane, prefix + "_plane", p.I32(prefix + "_frame").rows, 1);
  CheckIndex(plane, prefix + "_plane", p.F64("planes").rows);
}

void AddPlaneTerm(ProblemBuilder& builder, int term_id) {
  const TermSpec& spec = Terms()[term_id];
  const ProblemData& data = builder.data();
  const std::string prefix = spec.points;
  const ArrayRef<int32_t> frame = data.I32(prefix + "_frame");
  const ArrayRef<double> p_in_cam = data.F64(prefix + "_p_in_cam");
  const ArrayRef<int32_t> plane = data.I32(prefix + "_plane");
  const bool facap = builder.options().plane_mode == PlaneMode::kFacap;
  if (facap && !builder.state().facap_plane_valid[term_id]) {
    builder.blocks(term_id) = TermBlocks();
    builder.blocks(term_id).num_skipped = frame.rows;
    return;
  }
  if (!builder.Prepare(term_id, frame.rows, builder.options().term(term_id).sigma, 1)) return;
  TermBlocks& term = builder.blocks(term_id);
  double* facap_plane = builder.FacapPlane(term_id);
  for (int64_t i = 0; i < frame.rows; ++i) {
    const Eigen::Vector3d p(p_in_cam(i, 0), p_in_cam(i, 1), p_in_cam(i, 2));
    if (facap) {
      builder.AddObservation(PointToVariablePlaneCostFunctor::Create(p, term.sqrt_weight),
                             {builder.Pose(frame(i)), facap_plane});
    } else {
      const double* pl = data.F64("planes").row(plane(i));
      builder.AddObservation(PointToPlaneCostFunction::Create(
                                 p, Eigen::Vector4d(pl[0], pl[1], pl[2], pl[3]), term.sqrt_weight),
                             {builder.Pose(frame(i))});
    }
  }
  term.num_residual_blocks = frame.rows;
}

}  // namespace

TermSpec FloorTerm() {
  return TermSpec{"F",
                  "floor",
                  "floor",
                  "floor points to the floor plane, n·(world_from_cam p) + d (m)",
                  /*paper_term=*/true,
                  /*bim_term=*/true,
                  TermOptions{true, 0.02, 1.0, 0.02, LossType::kHuber, 1.0, {}},
                  {{"floor_frame", DType::kInt32, 0},
                   {"floor_p_in_cam", DType::kFloat64, 3},
                   {"floor_plane", DType::kInt32, 0},
                   {"planes", DType::kFloat64, 4}},
                  {},
                  /*segment_class=*/0,
                  /*facap_plane=*/true,
                  /*points=*/"floor",
                  [](const ProblemData& p) { CheckPlaneTerm(p, "floor"); },
                  AddPlaneTerm};
}

TermSpec CeilingTerm() {
  return TermSpec{"Ce",
                  "ceiling",
                  "ceiling",
                  "ceiling points to the ceiling plane, n·(world_from_cam p) + d (m)",
                  /*paper_term=*/true,
                  /*bim_term=*/true,
                  TermOptions{true, 0.02, 1.0, 0.02, LossType::kHuber, 1.0, {}},
                  {{"ceiling_frame", DType::kInt32, 0},
                   {"ceiling_p_in_cam", DType::kFloat64, 3},
                   {"ceiling_plane", DType::kInt32, 0},
                   {"planes", DType::kFloat64, 4}},
                  {},
                  /*segment_class=*/0,
                  /*facap_plane=*/true,
                  /*points=*/"ceiling",
                  [](const ProblemData& p) { CheckPlaneTerm(p, "ceiling"); },
                  AddPlaneTerm};
}

}  // namespace bimcap
