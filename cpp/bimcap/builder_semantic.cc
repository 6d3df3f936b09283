// The BIM terms F, Ce, W, Co (its own translation unit: the autodiff instantiations are heavy).
#include "bimcap/builder.h"
#include "bimcap/cost_functions/point_to_plane.h"
#include "bimcap/cost_functions/point_to_segment.h"

namespace bimcap {

void ProblemBuilder::AddPlaneTerm(int term_id, const ArrayRef<int32_t>& frame,
                                  const ArrayRef<double>& p_in_cam, const ArrayRef<int32_t>& plane,
                                  int facap_slot) {
  const bool facap = options_.plane_mode == PlaneMode::kFacap;
  if (facap && !state_->facap_plane_valid[facap_slot]) {
    terms_[term_id] = TermBlocks();
    terms_[term_id].num_skipped = frame.rows;
    return;
  }
  if (!Prepare(term_id, frame.rows, options_.term(term_id).sigma, 1)) return;
  TermBlocks& term = terms_[term_id];
  ceres::LossFunction* loss = losses_[term_id].get();
  double* facap_plane = state_->facap_planes.data() + 4 * facap_slot;
  for (int64_t i = 0; i < frame.rows; ++i) {
    const Eigen::Vector3d p(p_in_cam(i, 0), p_in_cam(i, 1), p_in_cam(i, 2));
    if (facap) {
      term.ids.push_back(problem_->AddResidualBlock(
          PointToVariablePlaneCostFunctor::Create(p, term.sqrt_weight), loss, Pose(frame(i)),
          facap_plane));
    } else {
      const double* pl = data_.planes.row(plane(i));
      term.ids.push_back(problem_->AddResidualBlock(
          PointToPlaneCostFunction::Create(p, Eigen::Vector4d(pl[0], pl[1], pl[2], pl[3]),
                                          term.sqrt_weight),
          loss, Pose(frame(i))));
    }
  }
  term.num_residual_blocks = frame.rows;
}

void ProblemBuilder::AddSegmentTerm(int term_id, const ArrayRef<int32_t>& frame,
                                    const ArrayRef<double>& p_in_cam,
                                    const std::vector<int>& association) {
  if (static_cast<int64_t>(association.size()) != frame.rows) {  // not associated (yet)
    terms_[term_id] = TermBlocks();
    terms_[term_id].num_skipped = frame.rows;
    return;
  }
  int64_t count = 0;
  for (int s : association) count += s >= 0 ? 1 : 0;
  if (!Prepare(term_id, count, options_.term(term_id).sigma, 1)) {
    terms_[term_id].num_skipped = frame.rows - count;
    return;
  }
  TermBlocks& term = terms_[term_id];
  term.num_skipped = frame.rows - count;
  ceres::LossFunction* loss = losses_[term_id].get();
  for (int64_t i = 0; i < frame.rows; ++i) {
    const int s = association[i];
    if (s < 0) continue;
    const double* seg = data_.segments.row(s);
    term.ids.push_back(problem_->AddResidualBlock(
        PointToSegmentCostFunction::Create(
            Eigen::Vector3d(p_in_cam(i, 0), p_in_cam(i, 1), p_in_cam(i, 2)),
            Eigen::Vector4d(seg[0], seg[1], seg[2], seg[3]), term.sqrt_weight),
        loss, Pose(frame(i))));
  }
  term.num_residual_blocks = count;
}

}  // namespace bimcap
