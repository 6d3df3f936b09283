// The odometry (ROBUST weighting only, not a paper term): each pair of consecutive frames (not
// both fixed) keeps the input's relative motion,
// r = [(t_ab − t_ab0) / sigma (m, in frame a) ; 2 vec(q_ab0⁻¹ q_ab) / sigma_r] (whitened,
// relative_pose.h), plain L2. A frame that neither the BIM nor G can place follows its
// neighbours instead of staying where the drift put it.
#include <cmath>
#include <vector>

#include "bimcap/builder.h"
#include "bimcap/cost_functions/relative_pose.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

void AddOdometry(ProblemBuilder& builder, int term_id) {
  const ProblemData& data = builder.data();
  std::vector<int64_t> pairs;  // a of each consecutive pair (a, a + 1)
  for (int64_t a = 0; a + 1 < data.num_poses(); ++a) {
    if (data.pose_fixed(a) != 0 && data.pose_fixed(a + 1) != 0) continue;
    pairs.push_back(a);
  }
  // The functor whitens, so s = 1.
  if (!builder.Prepare(term_id, static_cast<int64_t>(pairs.size()), 1.0, 6)) return;
  TermBlocks& term = builder.blocks(term_id);
  ceres::LossFunction* loss = builder.mutable_loss(term_id);
  const TermOptions& options = builder.options().term(term_id);
  const double sigma_t = options.sigma;
  const double sigma_r = options.param("sigma_r_deg") * M_PI / 180.0;
  for (const int64_t a : pairs) {
    term.ids.push_back(builder.problem().AddResidualBlock(
        RelativePoseCostFunctor::Create(data.poses.row(a), data.poses.row(a + 1), sigma_t, sigma_r),
        loss, builder.Pose(a), builder.Pose(a + 1)));
  }
  term.num_residual_blocks = static_cast<int64_t>(pairs.size());
}

}  // namespace

TermSpec OdometryTerm() {
  return TermSpec{
      "odometry",
      "odometry",
      "odometry",
      "consecutive frames keep the input's relative motion: translation / sigma (m), rotation "
      "/ sigma_r_deg",
      /*paper_term=*/false,
      /*bim_term=*/false,
      TermOptions{true, 0.0, 1.0, 0.3, LossType::kNone, 1.0, {}},
      /*arrays=*/{},
      {{"sigma_r_deg", 15.0, "the rotation scale, degrees"}},
      /*segment_class=*/0,
      /*facap_plane=*/false,
      /*points=*/"",
      [](const ProblemData&) {},
      AddOdometry};
}

}  // namespace bimcap
