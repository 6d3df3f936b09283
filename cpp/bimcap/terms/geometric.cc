// G, the geometric term, and the landmark depth prior that goes with its landmark form. G's
// residual by GeometricMode: kPoint, two back-projected matched points coincide in the world
// (3, m, point_consistency.h); kReprojection, a point back-projected in one frame reprojects
// onto its match in the other (2, px, reprojection.h); kLandmark, bundle adjustment with one
// landmark per track (2, px, landmark.h) plus the depth prior.
#include <string>

#include "bimcap/builder.h"
#include "bimcap/checks.h"
#include "bimcap/cost_functions/landmark.h"
#include "bimcap/cost_functions/point_consistency.h"
#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/terms.h"

namespace bimcap {
namespace {

// G as point consistency (kPoint) or two-frame reprojection (kReprojection).
void AddMatches(ProblemBuilder& builder, int term_id) {
  const ProblemData& data = builder.data();
  const SolverOptions& options = builder.options();
  const ArrayRef<int32_t> match_frames = data.I32("match_frames");
  const ArrayRef<double> match_uv = data.F64("match_uv");
  const ArrayRef<double> match_depth = data.F64("match_depth");
  const TermOptions& depth_options = options.term("depth");
  const int64_t m = match_frames.rows;
  const bool reprojection = options.geometric_mode == GeometricMode::kReprojection;
  // Observations: point mode needs both depths; reprojection uses each direction whose source
  // depth is known (a→b needs depth_a, b→a needs depth_b).
  int64_t count = 0, skipped = 0;
  for (int64_t i = 0; i < m; ++i) {
    const bool da = match_depth(i, 0) > 0, db = match_depth(i, 1) > 0;
    if (reprojection) {
      count += static_cast<int64_t>(da) + static_cast<int64_t>(db);
      skipped += static_cast<int64_t>(!da) + static_cast<int64_t>(!db);
    } else {
      count += (da && db) ? 1 : 0;
      skipped += (da && db) ? 0 : 1;
    }
  }
  const double sigma = reprojection ? options.pixel_sigma : options.term(term_id).sigma;
  if (!builder.Prepare(term_id, count, sigma, reprojection ? 2 : 3)) return;
  TermBlocks& term = builder.blocks(term_id);
  term.num_skipped = skipped;
  const double s = term.sqrt_weight;
  // Reprojection in robust weighting whitens each error by its keypoint depth's noise
  // (depth.sigma, see reprojection.h); the peers' weighting keeps the plain error.
  const double pixel_sigma = options.pixel_sigma;
  const double depth_sigma = (options.weighting == Weighting::kRobust && depth_options.enabled)
                                 ? depth_options.sigma
                                 : 0.0;
  for (int64_t i = 0; i < m; ++i) {
    const int a = match_frames(i, 0), b = match_frames(i, 1);
    const double* uv = match_uv.row(i);
    const double depth_a = match_depth(i, 0), depth_b = match_depth(i, 1);
    const double* k_a = data.cameras.row(data.frame_camera(a));
    const double* k_b = data.cameras.row(data.frame_camera(b));
    if (reprojection) {
      if (depth_a > 0) {
        builder.AddReprojection(
            {Eigen::Vector4d(k_b[0], k_b[1], k_b[2], k_b[3]), s, pixel_sigma, depth_sigma},
            {BackprojectPixel(k_a, uv[0], uv[1], depth_a), Eigen::Vector2d(uv[2], uv[3])},
            builder.Pose(a), builder.Pose(b));
      }
      if (depth_b > 0) {
        builder.AddReprojection(
            {Eigen::Vector4d(k_a[0], k_a[1], k_a[2], k_a[3]), s, pixel_sigma, depth_sigma},
            {BackprojectPixel(k_b, uv[2], uv[3], depth_b), Eigen::Vector2d(uv[0], uv[1])},
            builder.Pose(b), builder.Pose(a));
      }
    } else if (depth_a > 0 && depth_b > 0) {
      builder.AddObservation(
          PointConsistencyCostFunction::Create(BackprojectPixel(k_a, uv[0], uv[1], depth_a),
                                               BackprojectPixel(k_b, uv[2], uv[3], depth_b), s),
          {builder.Pose(a), builder.Pose(b)});
    }
  }
  term.num_residual_blocks = count;
}

// G as landmark bundle adjustment: one reprojection per track observation (px).
void AddLandmarkObservations(ProblemBuilder& builder, int term_id) {
  const ProblemData& data = builder.data();
  const ArrayRef<int32_t> obs_frame = data.I32("track_obs_frame");
  const ArrayRef<int32_t> obs_point = data.I32("track_obs_point");
  const ArrayRef<double> obs_uv = data.F64("track_obs_uv");
  const int64_t k = obs_frame.rows;
  if (!builder.Prepare(term_id, k, builder.options().pixel_sigma, 2)) return;
  TermBlocks& term = builder.blocks(term_id);
  ceres::LossFunction* loss = builder.mutable_loss(term_id);
  for (int64_t i = 0; i < k; ++i) {
    const int f = obs_frame(i);
    const double* kf = data.cameras.row(data.frame_camera(f));
    term.ids.push_back(builder.problem().AddResidualBlock(
        LandmarkReprojectionCostFunction::Create(Eigen::Vector2d(obs_uv(i, 0), obs_uv(i, 1)),
                                                 Eigen::Vector4d(kf[0], kf[1], kf[2], kf[3]),
                                                 term.sqrt_weight),
        loss, builder.Pose(f), builder.TrackPoint(obs_point(i))));
  }
  term.num_residual_blocks = k;
  if (k > 0) builder.MarkLandmarks();
}

void AddGeometric(ProblemBuilder& builder, int term_id) {
  if (builder.options().geometric_mode == GeometricMode::kLandmark) {
    AddLandmarkObservations(builder, term_id);
  } else {
    AddMatches(builder, term_id);
  }
}

// The landmarks' depth prior (kLandmark only): the landmark's depth in the observing camera
// against the observation's depth, where known (m, landmark.h).
void AddLandmarkDepth(ProblemBuilder& builder, int term_id) {
  if (builder.options().geometric_mode != GeometricMode::kLandmark) return;
  const ProblemData& data = builder.data();
  const ArrayRef<int32_t> obs_frame = data.I32("track_obs_frame");
  const ArrayRef<int32_t> obs_point = data.I32("track_obs_point");
  const ArrayRef<double> obs_depth = data.F64("track_obs_depth");
  const int64_t k = obs_frame.rows;
  int64_t with_depth = 0;
  for (int64_t i = 0; i < k; ++i) with_depth += obs_depth(i) > 0 ? 1 : 0;
  if (!builder.Prepare(term_id, with_depth, builder.options().term(term_id).sigma, 1)) return;
  TermBlocks& term = builder.blocks(term_id);
  term.num_skipped = k - with_depth;
  ceres::LossFunction* loss = builder.mutable_loss(term_id);
  for (int64_t i = 0; i < k; ++i) {
    if (!(obs_depth(i) > 0)) continue;
    term.ids.push_back(builder.problem().AddResidualBlock(
        LandmarkDepthCostFunctor::Create(obs_depth(i), term.sqrt_weight), loss,
        builder.Pose(obs_frame(i)), builder.TrackPoint(obs_point(i))));
  }
  term.num_residual_blocks = static_cast<int64_t>(term.ids.size());
  if (!term.ids.empty()) builder.MarkLandmarks();
}

void CheckGeometric(const ProblemData& p) {
  const int64_t n = p.num_poses();
  // Matches.
  const ArrayRef<int32_t> match_frames = p.I32("match_frames");
  const int64_t m = match_frames.rows;
  CheckShape(match_frames, "match_frames", m, 2);
  CheckShape(p.F64("match_uv"), "match_uv", m, 4);
  CheckShape(p.F64("match_depth"), "match_depth", m, 2);
  CheckIndex(match_frames, "match_frames", n);
  CheckFinite(p.F64("match_uv"), "match_uv");
  CheckFinite(p.F64("match_depth"), "match_depth");
  for (int64_t i = 0; i < m; ++i) {
    if (match_frames(i, 0) == match_frames(i, 1)) {
      throw ProblemError("match_frames", "row " + std::to_string(i) + " matches frame " +
                                             std::to_string(match_frames(i, 0)) + " with itself");
    }
  }
  // Tracks.
  const int64_t k = p.I32("track_obs_frame").rows;
  const int64_t num_points = p.F64("track_points").rows;
  CheckShape(p.I32("track_obs_frame"), "track_obs_frame", k, 1);
  CheckShape(p.I32("track_obs_point"), "track_obs_point", k, 1);
  CheckShape(p.F64("track_obs_uv"), "track_obs_uv", k, 2);
  CheckShape(p.F64("track_obs_depth"), "track_obs_depth", k, 1);
  CheckShape(p.F64("track_points"), "track_points", num_points, 3);
  CheckIndex(p.I32("track_obs_frame"), "track_obs_frame", n);
  CheckIndex(p.I32("track_obs_point"), "track_obs_point", num_points);
  CheckFinite(p.F64("track_obs_uv"), "track_obs_uv");
  CheckFinite(p.F64("track_obs_depth"), "track_obs_depth");
  CheckFinite(p.F64("track_points"), "track_points");
}

}  // namespace

TermSpec GeometricTerm() {
  return TermSpec{
      "G",
      "geometric",
      "geometric",
      "feature matches: point consistency (m), two-frame reprojection (px) or landmark BA (px)",
      /*paper_term=*/true,
      /*bim_term=*/false,
      TermOptions{true, 1.0, 1.0, 0.05, LossType::kHuber, 1.0, {}},
      {{"match_frames", DType::kInt32, 2},
       {"match_uv", DType::kFloat64, 4},
       {"match_depth", DType::kFloat64, 2},
       {"track_obs_frame", DType::kInt32, 0},
       {"track_obs_point", DType::kInt32, 0},
       {"track_obs_uv", DType::kFloat64, 2},
       {"track_obs_depth", DType::kFloat64, 0},
       {"track_points", DType::kFloat64, 3}},
      {},
      /*segment_class=*/0,
      /*facap_plane=*/false,
      /*points=*/"",
      CheckGeometric,
      AddGeometric};
}

TermSpec LandmarkDepthTerm() {
  return TermSpec{
      "depth",
      "depth",
      "landmark depth",
      "landmark BA only: a landmark's depth in its camera against the observed depth (m)",
      /*paper_term=*/true,
      /*bim_term=*/false,
      TermOptions{true, 1.0, 1.0, 0.05, LossType::kHuber, 1.0, {}},
      {{"track_obs_depth", DType::kFloat64, 0}},
      {},
      /*segment_class=*/0,
      /*facap_plane=*/false,
      /*points=*/"",
      [](const ProblemData&) {},  // its arrays are G's, checked there
      AddLandmarkDepth};
}

}  // namespace bimcap
