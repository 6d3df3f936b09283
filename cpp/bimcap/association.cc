#include "bimcap/association.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "bimcap/cost_functions/point_to_segment.h"
#include "bimcap/pose.h"

namespace bimcap {
namespace {
constexpr int64_t kMaxCellsPerAxis = 2048;
}  // namespace

SegmentIndex::SegmentIndex(const ArrayRef<double>& segments, const ArrayRef<int32_t>& segment_class,
                           const ArrayRef<double>& segment_z,
                           const ArrayRef<double>& segment_normal, int32_t label, double gate)
    : segments_(segments), segment_z_(segment_z), segment_normal_(segment_normal), gate_(gate) {
  double xmin = std::numeric_limits<double>::infinity(), ymin = xmin;
  double xmax = -xmin, ymax = -xmin;
  for (int64_t s = 0; s < segments.rows; ++s) {
    if (segment_class(s) != label) continue;
    ids_.push_back(static_cast<int>(s));
    const double* seg = segments.row(s);
    xmin = std::min({xmin, seg[0], seg[2]});
    xmax = std::max({xmax, seg[0], seg[2]});
    ymin = std::min({ymin, seg[1], seg[3]});
    ymax = std::max({ymax, seg[1], seg[3]});
  }
  if (ids_.empty()) return;
  x0_ = xmin - gate_;
  y0_ = ymin - gate_;
  const double width = xmax - xmin + 2 * gate_, height = ymax - ymin + 2 * gate_;
  cell_ = std::max({gate_, width / kMaxCellsPerAxis, height / kMaxCellsPerAxis, 1e-6});
  nx_ = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(width / cell_)));
  ny_ = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(height / cell_)));

  // Two passes (count, fill) into a compressed cell → segments table.
  auto cell_range = [&](int s, int64_t* cx0, int64_t* cx1, int64_t* cy0, int64_t* cy1) {
    const double* seg = segments.row(s);
    const auto clampx = [&](double v) {
      return std::clamp<int64_t>(static_cast<int64_t>(std::floor((v - x0_) / cell_)), 0, nx_ - 1);
    };
    const auto clampy = [&](double v) {
      return std::clamp<int64_t>(static_cast<int64_t>(std::floor((v - y0_) / cell_)), 0, ny_ - 1);
    };
    *cx0 = clampx(std::min(seg[0], seg[2]) - gate_);
    *cx1 = clampx(std::max(seg[0], seg[2]) + gate_);
    *cy0 = clampy(std::min(seg[1], seg[3]) - gate_);
    *cy1 = clampy(std::max(seg[1], seg[3]) + gate_);
  };
  cell_start_.assign(nx_ * ny_ + 1, 0);
  for (int s : ids_) {
    int64_t cx0, cx1, cy0, cy1;
    cell_range(s, &cx0, &cx1, &cy0, &cy1);
    for (int64_t cy = cy0; cy <= cy1; ++cy)
      for (int64_t cx = cx0; cx <= cx1; ++cx) ++cell_start_[cy * nx_ + cx + 1];
  }
  for (size_t i = 1; i < cell_start_.size(); ++i) cell_start_[i] += cell_start_[i - 1];
  cell_items_.resize(cell_start_.back());
  std::vector<int64_t> fill(cell_start_.begin(), cell_start_.end() - 1);
  for (int s : ids_) {
    int64_t cx0, cx1, cy0, cy1;
    cell_range(s, &cx0, &cx1, &cy0, &cy1);
    for (int64_t cy = cy0; cy <= cy1; ++cy)
      for (int64_t cx = cx0; cx <= cx1; ++cx) cell_items_[fill[cy * nx_ + cx]++] = s;
  }
}

int SegmentIndex::Nearest(double x, double y, double z, double cam_x, double cam_y,
                          double* distance) const {
  if (ids_.empty() || !std::isfinite(x) || !std::isfinite(y)) return -1;
  const double fx = std::floor((x - x0_) / cell_), fy = std::floor((y - y0_) / cell_);
  if (fx < 0 || fy < 0 || fx >= static_cast<double>(nx_) || fy >= static_cast<double>(ny_)) {
    return -1;  // outside every inflated bounding box: nothing within the gate
  }
  const int64_t cell = static_cast<int64_t>(fy) * nx_ + static_cast<int64_t>(fx);
  int best = -1;
  double best_distance = gate_;
  for (int64_t i = cell_start_[cell]; i < cell_start_[cell + 1]; ++i) {
    const int s = cell_items_[i];
    if (z < segment_z_(s, 0) || z > segment_z_(s, 1)) continue;
    if (!segment_normal_.empty()) {
      const double nx = segment_normal_(s, 0), ny = segment_normal_(s, 1);
      if ((nx != 0.0 || ny != 0.0) &&
          nx * (cam_x - segments_(s, 0)) + ny * (cam_y - segments_(s, 1)) <= 0.0) {
        continue;  // the camera is behind this face: it cannot have seen it
      }
    }
    const Eigen::Vector4d seg(segments_(s, 0), segments_(s, 1), segments_(s, 2), segments_(s, 3));
    const double d = std::abs(PointToSegmentDistance2D(x, y, seg));
    // Ties go to the lower index so that the association is deterministic.
    if (d < best_distance || (d == best_distance && (best < 0 || s < best))) {
      best = s;
      best_distance = d;
    }
  }
  if (best >= 0 && distance != nullptr) *distance = best_distance;
  return best;
}

std::vector<int> AssociatePoints(const SegmentIndex& index, const ArrayRef<int32_t>& frame,
                                 const ArrayRef<double>& p_in_cam, const double* poses,
                                 const std::vector<int>& previous, AssociationStats* stats) {
  std::vector<int> assoc(frame.rows, -1);
  AssociationStats s;
  s.num_points = frame.rows;
  double sum = 0.0;
  for (int64_t i = 0; i < frame.rows; ++i) {
    const Eigen::Vector3d p(p_in_cam(i, 0), p_in_cam(i, 1), p_in_cam(i, 2));
    const double* pose = poses + kPoseSize * frame(i);  // tx ty tz qx qy qz qw
    const Eigen::Vector3d w = CamToWorld(pose, p);
    double d = 0.0;
    assoc[i] = index.Nearest(w.x(), w.y(), w.z(), pose[0], pose[1], &d);
    if (assoc[i] >= 0) {
      ++s.num_associated;
      sum += d;
    } else {
      ++s.num_rejected;
    }
    if (previous.size() == assoc.size() && previous[i] != assoc[i]) ++s.num_changed;
  }
  if (previous.size() != assoc.size()) s.num_changed = s.num_associated;
  s.mean_distance = s.num_associated > 0 ? sum / s.num_associated : 0.0;
  if (stats != nullptr) *stats = s;
  return assoc;
}

}  // namespace bimcap
