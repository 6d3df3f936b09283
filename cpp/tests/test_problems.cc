#include "test_problems.h"

#include <Eigen/Geometry>
#include <cmath>
#include <random>

namespace bimcap::testing {
namespace {

constexpr double kFx = 400, kFy = 400, kCx = 319.5, kCy = 239.5, kW = 640, kH = 480;
constexpr double kRoomX = 10, kRoomY = 6, kHeight = 3;

template <typename T>
ArrayRef<T> Ref(const std::vector<T>& v, int64_t cols) {
  return ArrayRef<T>{v.empty() ? nullptr : v.data(), static_cast<int64_t>(v.size()) / cols, cols};
}

struct Pose {
  Eigen::Quaterniond q;
  Eigen::Vector3d t;
  Eigen::Vector3d ToCam(const Eigen::Vector3d& w) const { return q.conjugate() * (w - t); }
};

bool Project(const Eigen::Vector3d& p, Eigen::Vector2d* uv) {
  if (p.z() < 0.3 || p.z() > 10) return false;
  *uv = Eigen::Vector2d(kFx * p.x() / p.z() + kCx, kFy * p.y() / p.z() + kCy);
  return uv->x() >= 0 && uv->x() <= kW - 1 && uv->y() >= 0 && uv->y() <= kH - 1;
}

void Push(std::vector<double>* v, const Eigen::Vector3d& p) {
  v->insert(v->end(), {p.x(), p.y(), p.z()});
}

}  // namespace

ProblemData OwnedProblem::View() const {
  ProblemData p;
  p.poses = Ref(poses, 7);
  p.timestamps = Ref(timestamps, 1);
  p.pose_fixed = Ref(pose_fixed, 1);
  p.cameras = Ref(cameras, 4);
  p.frame_camera = Ref(frame_camera, 1);
  p.Set("match_frames", Ref(match_frames, 2));
  p.Set("match_uv", Ref(match_uv, 4));
  p.Set("match_depth", Ref(match_depth, 2));
  p.Set("track_obs_frame", Ref(track_obs_frame, 1));
  p.Set("track_obs_point", Ref(track_obs_point, 1));
  p.Set("track_obs_uv", Ref(track_obs_uv, 2));
  p.Set("track_obs_depth", Ref(track_obs_depth, 1));
  p.Set("track_points", Ref(track_points, 3));
  p.Set("floor_frame", Ref(floor_frame, 1));
  p.Set("floor_p_in_cam", Ref(floor_p_in_cam, 3));
  p.Set("floor_plane", Ref(floor_plane, 1));
  p.Set("ceiling_frame", Ref(ceiling_frame, 1));
  p.Set("ceiling_p_in_cam", Ref(ceiling_p_in_cam, 3));
  p.Set("ceiling_plane", Ref(ceiling_plane, 1));
  p.Set("planes", Ref(planes, 4));
  p.Set("wall_frame", Ref(wall_frame, 1));
  p.Set("wall_p_in_cam", Ref(wall_p_in_cam, 3));
  p.Set("column_frame", Ref(column_frame, 1));
  p.Set("column_p_in_cam", Ref(column_p_in_cam, 3));
  p.Set("segments", Ref(segments, 4));
  p.Set("segment_class", Ref(segment_class, 1));
  p.Set("segment_z", Ref(segment_z, 2));
  return p;
}

OwnedProblem MakeTestProblem(const TestProblemOptions& o) {
  std::mt19937 rng(o.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  OwnedProblem p;
  const int n = o.num_frames;
  p.cameras = {kFx, kFy, kCx, kCy};
  p.planes = {0, 0, 1, 0, 0, 0, 1, -kHeight};
  p.segments = {0,      0,      kRoomX, 0,      kRoomX, 0,      kRoomX, kRoomY,
                kRoomX, kRoomY, 0,      kRoomY, 0,      kRoomY, 0,      0};
  p.segment_class = {1, 1, 1, 1};
  const double c0 = 4.8, c1 = 5.2, r0 = 2.8, r1 = 3.2;  // column
  const double column[] = {c0, r0, c1, r0, c1, r0, c1, r1, c1, r1, c0, r1, c0, r1, c0, r0};
  p.segments.insert(p.segments.end(), column, column + 16);
  p.segment_class.insert(p.segment_class.end(), {4, 4, 4, 4});
  for (int s = 0; s < 8; ++s) p.segment_z.insert(p.segment_z.end(), {0.0, kHeight});

  // Ground truth: camera optical axes (x right, y down, z forward) looking along the loop.
  std::vector<Pose> gt(n), init(n);
  Eigen::Vector3d drift_t = Eigen::Vector3d::Zero();
  double drift_yaw = 0;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    const Eigen::Vector3d t(5 + 3.2 * std::cos(a), 3 + 1.6 * std::sin(a),
                            1.4 + 0.02 * std::sin(5 * a));
    const double yaw = std::atan2(1.6 * std::cos(a), -3.2 * std::sin(a)) + 0.25 * std::sin(3 * a);
    Eigen::Matrix3d base;
    base << 0, 0, 1, -1, 0, 0, 0, -1, 0;  // columns: x_cam, y_cam, z_cam in a yaw-0 world
    const Eigen::Matrix3d r = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                              Eigen::AngleAxisd(0.05 * std::sin(2 * a), Eigen::Vector3d::UnitY()) *
                              base;
    gt[i] = {Eigen::Quaterniond(r).normalized(), t};
    if (i > 0) {
      drift_t += o.drift_translation * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
      drift_yaw += o.drift_yaw_deg * M_PI / 180 * normal(rng);
    }
    init[i] = {(Eigen::AngleAxisd(drift_yaw, Eigen::Vector3d::UnitZ()) * gt[i].q).normalized(),
               gt[i].t + drift_t};
    for (const Pose* pose : {&gt[i], &init[i]}) {
      auto& out = pose == &gt[i] ? p.gt_poses : p.poses;
      out.insert(out.end(), {pose->t.x(), pose->t.y(), pose->t.z(), pose->q.x(), pose->q.y(),
                             pose->q.z(), pose->q.w()});
    }
    p.timestamps.push_back(0.1 * i);
    p.pose_fixed.push_back(i == 0 ? 1 : 0);
    p.frame_camera.push_back(0);
  }

  auto noisy = [&](const Eigen::Vector3d& v, double s) {
    return Eigen::Vector3d(v.x() + s * normal(rng), v.y() + s * normal(rng),
                           v.z() + s * normal(rng));
  };
  auto wall_point = [&](int segment) {
    const double* s = &p.segments[4 * segment];
    const double u = unit(rng);
    return Eigen::Vector3d(s[0] + u * (s[2] - s[0]), s[1] + u * (s[3] - s[1]),
                           0.1 + 2.8 * unit(rng));
  };
  // Semantic observations.
  for (int i = 0; i < n; ++i) {
    int floor = 0, ceiling = 0, wall = 0, col = 0;
    for (int tries = 0; tries < 4000 && (floor < 30 || ceiling < 20 || wall < 40 || col < 8);
         ++tries) {
      const int kind = tries % 4;
      Eigen::Vector3d w;
      if (kind == 0) w = {kRoomX * unit(rng), kRoomY * unit(rng), 0};
      if (kind == 1) w = {kRoomX * unit(rng), kRoomY * unit(rng), kHeight};
      if (kind == 2) w = wall_point(static_cast<int>(4 * unit(rng)) % 4);
      if (kind == 3) w = wall_point(4 + static_cast<int>(4 * unit(rng)) % 4);
      const Eigen::Vector3d c = gt[i].ToCam(w);
      Eigen::Vector2d uv;
      if (!Project(c, &uv)) continue;
      const Eigen::Vector3d m = noisy(c, o.point_noise);
      if (kind == 0 && floor < 30) {
        ++floor;
        p.floor_frame.push_back(i);
        Push(&p.floor_p_in_cam, m);
        p.floor_plane.push_back(0);
      } else if (kind == 1 && ceiling < 20) {
        ++ceiling;
        p.ceiling_frame.push_back(i);
        Push(&p.ceiling_p_in_cam, m);
        p.ceiling_plane.push_back(1);
      } else if (kind == 2 && wall < 40) {
        ++wall;
        p.wall_frame.push_back(i);
        Push(&p.wall_p_in_cam, m);
      } else if (kind == 3 && col < 8) {
        ++col;
        p.column_frame.push_back(i);
        Push(&p.column_p_in_cam, m);
      }
    }
  }
  // G matches between i and i + 1, i + 2.
  for (int i = 0; i < n; ++i) {
    for (int off = 1; off <= 2 && i + off < n; ++off) {
      const int j = i + off;
      int count = 0;
      for (int tries = 0; tries < 2000 && count < 25; ++tries) {
        const Eigen::Vector3d w = wall_point(static_cast<int>(4 * unit(rng)) % 4);
        Eigen::Vector2d ua, ub;
        const Eigen::Vector3d ca = gt[i].ToCam(w), cb = gt[j].ToCam(w);
        if (!Project(ca, &ua) || !Project(cb, &ub)) continue;
        ++count;
        p.match_frames.insert(p.match_frames.end(), {i, j});
        p.match_uv.insert(
            p.match_uv.end(),
            {ua.x() + o.pixel_noise * normal(rng), ua.y() + o.pixel_noise * normal(rng),
             ub.x() + o.pixel_noise * normal(rng), ub.y() + o.pixel_noise * normal(rng)});
        p.match_depth.insert(p.match_depth.end(), {ca.z() + o.point_noise * normal(rng),
                                                   cb.z() + o.point_noise * normal(rng)});
      }
    }
  }
  // Landmarks: a pool of wall points; every frame observes those it sees.
  const int num_points = 15 * n;
  for (int k = 0; k < num_points; ++k)
    Push(&p.gt_points, wall_point(static_cast<int>(4 * unit(rng)) % 4));
  std::vector<int> first_frame(num_points, -1);
  std::vector<Eigen::Vector3d> first_cam(num_points);
  for (int i = 0; i < n; ++i) {
    for (int k = 0; k < num_points; ++k) {
      const Eigen::Vector3d w(p.gt_points[3 * k], p.gt_points[3 * k + 1], p.gt_points[3 * k + 2]);
      const Eigen::Vector3d c = gt[i].ToCam(w);
      Eigen::Vector2d uv;
      if (!Project(c, &uv)) continue;
      p.track_obs_frame.push_back(i);
      p.track_obs_point.push_back(k);
      p.track_obs_uv.insert(p.track_obs_uv.end(), {uv.x() + o.pixel_noise * normal(rng),
                                                   uv.y() + o.pixel_noise * normal(rng)});
      p.track_obs_depth.push_back(c.z() + o.point_noise * normal(rng));
      if (first_frame[k] < 0) {
        first_frame[k] = i;
        first_cam[k] = c;
      }
    }
  }
  // Initial landmarks: the first observation placed with the drifted pose.
  for (int k = 0; k < num_points; ++k) {
    const Eigen::Vector3d w =
        first_frame[k] < 0
            ? Eigen::Vector3d(p.gt_points[3 * k], p.gt_points[3 * k + 1], p.gt_points[3 * k + 2])
            : Eigen::Vector3d(init[first_frame[k]].q * first_cam[k] + init[first_frame[k]].t);
    Push(&p.track_points, w);
  }
  return p;
}

void PoseErrors(const std::vector<double>& poses, const std::vector<double>& gt, double* trans_rmse,
                double* rot_rmse_deg) {
  const size_t n = poses.size() / 7;
  double st = 0, sr = 0;
  for (size_t i = 0; i < n; ++i) {
    const double* a = &poses[7 * i];
    const double* b = &gt[7 * i];
    st += (Eigen::Vector3d(a[0], a[1], a[2]) - Eigen::Vector3d(b[0], b[1], b[2])).squaredNorm();
    const Eigen::Quaterniond qa(a[6], a[3], a[4], a[5]), qb(b[6], b[3], b[4], b[5]);
    const double angle = qa.angularDistance(qb) * 180 / M_PI;
    sr += angle * angle;
  }
  *trans_rmse = std::sqrt(st / n);
  *rot_rmse_deg = std::sqrt(sr / n);
}

Eigen::MatrixXd DenseJtJ(const ceres::CRSMatrix& jacobian) {
  Eigen::MatrixXd j = Eigen::MatrixXd::Zero(jacobian.num_rows, jacobian.num_cols);
  for (int row = 0; row < jacobian.num_rows; ++row) {
    for (int x = jacobian.rows[row]; x < jacobian.rows[row + 1]; ++x) {
      j(row, jacobian.cols[x]) = jacobian.values[x];
    }
  }
  return j.transpose() * j;
}

}  // namespace bimcap::testing
