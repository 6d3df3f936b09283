// The G term's residuals (its own translation unit: the autodiff instantiations are heavy).
#include "bimcap/builder.h"
#include "bimcap/cost_functions/landmark.h"
#include "bimcap/cost_functions/point_consistency.h"
#include "bimcap/cost_functions/reprojection.h"

namespace bimcap {

void ProblemBuilder::AddGeometric() {
  const int64_t m = data_.match_frames.rows;
  const bool reprojection = options_.geometric_mode == GeometricMode::kReprojection;
  // Observations: point mode needs both depths; reprojection uses each direction whose source
  // depth is known (a→b needs depth_a, b→a needs depth_b).
  int64_t count = 0, skipped = 0;
  for (int64_t i = 0; i < m; ++i) {
    const bool da = data_.match_depth(i, 0) > 0, db = data_.match_depth(i, 1) > 0;
    if (reprojection) {
      count += static_cast<int64_t>(da) + static_cast<int64_t>(db);
      skipped += static_cast<int64_t>(!da) + static_cast<int64_t>(!db);
    } else {
      count += (da && db) ? 1 : 0;
      skipped += (da && db) ? 0 : 1;
    }
  }
  const double sigma = reprojection ? options_.pixel_sigma : options_.geometric.sigma;
  if (!Prepare(kTermG, count, sigma, reprojection ? 2 : 3)) return;
  TermBlocks& term = terms_[kTermG];
  term.num_skipped = skipped;
  ceres::LossFunction* loss = losses_[kTermG].get();
  const double s = term.sqrt_weight;
  // Reprojection in robust weighting whitens each error by its keypoint depth's noise
  // (depth.sigma, see reprojection.h); the peers' weighting keeps the plain error.
  const double pixel_sigma = options_.pixel_sigma;
  const double depth_sigma = (options_.weighting == Weighting::kRobust && options_.depth.enabled)
                                 ? options_.depth.sigma
                                 : 0.0;
  for (int64_t i = 0; i < m; ++i) {
    const int a = data_.match_frames(i, 0), b = data_.match_frames(i, 1);
    const double* uv = data_.match_uv.row(i);
    const double depth_a = data_.match_depth(i, 0), depth_b = data_.match_depth(i, 1);
    const double* k_a = data_.cameras.row(data_.frame_camera(a));
    const double* k_b = data_.cameras.row(data_.frame_camera(b));
    if (reprojection) {
      if (depth_a > 0) {
        term.ids.push_back(problem_->AddResidualBlock(
            ReprojectionCostFunctor::Create(BackprojectPixel(k_a, uv[0], uv[1], depth_a),
                                            Eigen::Vector2d(uv[2], uv[3]),
                                            Eigen::Vector4d(k_b[0], k_b[1], k_b[2], k_b[3]), s,
                                            pixel_sigma, depth_sigma),
            loss, Pose(a), Pose(b)));
      }
      if (depth_b > 0) {
        term.ids.push_back(problem_->AddResidualBlock(
            ReprojectionCostFunctor::Create(BackprojectPixel(k_b, uv[2], uv[3], depth_b),
                                            Eigen::Vector2d(uv[0], uv[1]),
                                            Eigen::Vector4d(k_a[0], k_a[1], k_a[2], k_a[3]), s,
                                            pixel_sigma, depth_sigma),
            loss, Pose(b), Pose(a)));
      }
    } else if (depth_a > 0 && depth_b > 0) {
      term.ids.push_back(problem_->AddResidualBlock(
          PointConsistencyCostFunction::Create(BackprojectPixel(k_a, uv[0], uv[1], depth_a),
                                              BackprojectPixel(k_b, uv[2], uv[3], depth_b), s),
          loss, Pose(a), Pose(b)));
    }
  }
  term.num_residual_blocks = static_cast<int64_t>(term.ids.size());
}

void ProblemBuilder::AddLandmarks() {
  const int64_t k = data_.track_obs_frame.rows;
  int64_t with_depth = 0;
  for (int64_t i = 0; i < k; ++i) with_depth += data_.track_obs_depth(i) > 0 ? 1 : 0;

  if (Prepare(kTermG, k, options_.pixel_sigma, 2)) {
    TermBlocks& term = terms_[kTermG];
    ceres::LossFunction* loss = losses_[kTermG].get();
    for (int64_t i = 0; i < k; ++i) {
      const int f = data_.track_obs_frame(i);
      const double* kf = data_.cameras.row(data_.frame_camera(f));
      term.ids.push_back(problem_->AddResidualBlock(
          LandmarkReprojectionCostFunction::Create(
              Eigen::Vector2d(data_.track_obs_uv(i, 0), data_.track_obs_uv(i, 1)),
              Eigen::Vector4d(kf[0], kf[1], kf[2], kf[3]), term.sqrt_weight),
          loss, Pose(f), state_->track_points.data() + 3 * data_.track_obs_point(i)));
    }
    term.num_residual_blocks = k;
    has_landmarks_ = k > 0;
  }
  if (Prepare(kTermDepth, with_depth, options_.depth.sigma, 1)) {
    TermBlocks& term = terms_[kTermDepth];
    term.num_skipped = k - with_depth;
    ceres::LossFunction* loss = losses_[kTermDepth].get();
    for (int64_t i = 0; i < k; ++i) {
      if (!(data_.track_obs_depth(i) > 0)) continue;
      const int f = data_.track_obs_frame(i);
      term.ids.push_back(problem_->AddResidualBlock(
          LandmarkDepthCostFunctor::Create(data_.track_obs_depth(i), term.sqrt_weight), loss,
          Pose(f), state_->track_points.data() + 3 * data_.track_obs_point(i)));
    }
    term.num_residual_blocks = static_cast<int64_t>(term.ids.size());
    has_landmarks_ = has_landmarks_ || !term.ids.empty();
  }
}

}  // namespace bimcap
