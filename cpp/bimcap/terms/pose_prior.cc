// The pose prior (ROBUST weighting only, not a paper term): each free pose that the terms
// before it put into the problem is held near its input pose,
// r = [(t − t0) / sigma ; 2 vec(q0⁻¹ q) / sigma_r] (whitened, pose_prior.h), plain L2. It
// anchors the degrees of freedom the other terms leave unobserved.
#include "bimcap/cost_functions/pose_prior.h"

#include <cmath>
#include <vector>

#include "bimcap/builder.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

void AddPosePrior(ProblemBuilder& builder, int term_id) {
  const ProblemData& data = builder.data();
  std::vector<int64_t> free;
  for (int64_t i = 0; i < data.num_poses(); ++i) {
    if (data.pose_fixed(i) == 0 && builder.problem().HasParameterBlock(builder.Pose(i))) {
      free.push_back(i);
    }
  }
  // The functor whitens, so s = 1.
  if (!builder.Prepare(term_id, static_cast<int64_t>(free.size()), 1.0, 6)) return;
  TermBlocks& term = builder.blocks(term_id);
  ceres::LossFunction* loss = builder.mutable_loss(term_id);
  const TermOptions& options = builder.options().term(term_id);
  const double sigma_t = options.sigma;
  const double sigma_r = options.param("sigma_r_deg") * M_PI / 180.0;
  for (const int64_t i : free) {
    // The prior mean is the input pose (the problem data is never written; the state is a copy).
    term.ids.push_back(builder.problem().AddResidualBlock(
        PosePriorCostFunctor::Create(data.poses.row(i), sigma_t, sigma_r), loss, builder.Pose(i)));
  }
  term.num_residual_blocks = static_cast<int64_t>(free.size());
}

}  // namespace

TermSpec PosePriorTerm() {
  return TermSpec{
      "prior",
      "prior",
      "pose prior",
      "each free pose near its input pose: translation / sigma (m), rotation / sigma_r_deg",
      /*paper_term=*/false,
      /*bim_term=*/false,
      TermOptions{true, 0.0, 1.0, 2.0, LossType::kNone, 1.0, {}},
      /*arrays=*/{},
      {{"sigma_r_deg", 20.0, "the rotation scale, degrees"}},
      /*segment_class=*/0,
      /*facap_plane=*/false,
      /*points=*/"",
      [](const ProblemData&) {},
      AddPosePrior};
}

}  // namespace bimcap
