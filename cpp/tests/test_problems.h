// A small synthetic problem with ground truth for the C++ tests (the Python generator in
// bimcap.optimize.synthetic is the full one): a 10 × 6 × 3 m room with four walls, one square
// column, floor z = 0 and ceiling z = 3; a camera on a loop at 1.4 m; noisy observations of every
// term; a drift of the initial poses that is zero at frame 0 (held fixed).
#ifndef BIMCAP_TESTS_TEST_PROBLEMS_H_
#define BIMCAP_TESTS_TEST_PROBLEMS_H_

#include <ceres/crs_matrix.h>

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "bimcap/problem.h"

namespace bimcap::testing {

struct OwnedProblem {
  std::vector<double> poses, timestamps, cameras;
  std::vector<int32_t> pose_fixed, frame_camera;
  std::vector<int32_t> match_frames;
  std::vector<double> match_uv, match_depth;
  std::vector<int32_t> track_obs_frame, track_obs_point;
  std::vector<double> track_obs_uv, track_obs_depth, track_points;
  std::vector<int32_t> floor_frame, floor_plane, ceiling_frame, ceiling_plane;
  std::vector<double> floor_p_in_cam, ceiling_p_in_cam, planes;
  std::vector<int32_t> wall_frame, column_frame, segment_class;
  std::vector<double> wall_p_in_cam, column_p_in_cam, segments, segment_z;

  std::vector<double> gt_poses;   // (N, 7)
  std::vector<double> gt_points;  // (P, 3)

  // Views of the vectors above (valid while this object lives and is not resized).
  ProblemData View() const;
};

struct TestProblemOptions {
  int num_frames = 30;
  double drift_translation = 0.02;  // per-frame random-walk sigma, m
  double drift_yaw_deg = 0.3;       // per-frame random-walk sigma, degrees
  double point_noise = 0.005;       // m
  double pixel_noise = 0.3;         // px
  unsigned seed = 1;
};

OwnedProblem MakeTestProblem(const TestProblemOptions& options = TestProblemOptions());

// RMS translation error (m) and RMS rotation error (degrees) of (N, 7) poses against the truth.
void PoseErrors(const std::vector<double>& poses, const std::vector<double>& gt, double* trans_rmse,
                double* rot_rmse_deg);

// JᵀJ (dense) of a Jacobian that ceres::Problem::Evaluate returned.
Eigen::MatrixXd DenseJtJ(const ceres::CRSMatrix& jacobian);

}  // namespace bimcap::testing

#endif  // BIMCAP_TESTS_TEST_PROBLEMS_H_
