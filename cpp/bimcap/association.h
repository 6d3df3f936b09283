// Association of wall / column points with floor-plan segments.
//
// A point (in the world) is associated with the nearest segment of its class (xy distance, see
// PointToSegmentDistance2D) among the segments whose z range [zmin, zmax] holds the point's z,
// provided that distance is at most the gate. A uniform xy grid with cells of about the gate's
// size holds, in each cell, every segment whose gate-inflated bounding box touches the cell, so
// that one lookup returns every candidate: O(points × segments-per-cell), not points × segments.
//
// Visibility: with free-side normals n_s (optional `segment_normal`, unit, or zero for a face
// seen from both sides), segment s = (a, b) is admissible for a point observed from camera
// centre c only if c lies on its free side, n_s · (c_xy − a) > 0. A wall point can then never
// be associated with the far face of its wall (the outer face of an exterior wall is a
// wall-thickness alias, 0.2 m away, that the solver would otherwise settle into).
#ifndef BIMCAP_ASSOCIATION_H_
#define BIMCAP_ASSOCIATION_H_

#include <cstdint>
#include <vector>

#include "bimcap/problem.h"

namespace bimcap {

class SegmentIndex {
 public:
  // `segments` (S, 4), `segment_class` (S,), `segment_z` (S, 2), `segment_normal` (S, 2) or
  // empty (no visibility test) as in ProblemData; only segments of class `label` are indexed.
  // gate > 0 in metres.
  SegmentIndex(const ArrayRef<double>& segments, const ArrayRef<int32_t>& segment_class,
               const ArrayRef<double>& segment_z, const ArrayRef<double>& segment_normal,
               int32_t label, double gate);

  // The index of the nearest admissible segment within the gate for the world point (x, y, z)
  // seen from the camera centre (cam_x, cam_y), or -1. `distance` receives its unsigned xy
  // distance when found.
  int Nearest(double x, double y, double z, double cam_x, double cam_y, double* distance) const;

  int64_t num_segments() const { return static_cast<int64_t>(ids_.size()); }

 private:
  ArrayRef<double> segments_;
  ArrayRef<double> segment_z_;
  ArrayRef<double> segment_normal_;
  double gate_ = 0.0;
  double cell_ = 1.0;
  double x0_ = 0.0, y0_ = 0.0;
  int64_t nx_ = 0, ny_ = 0;
  std::vector<int> ids_;             // indexed segments
  std::vector<int64_t> cell_start_;  // CSR: cell → range in cell_items_
  std::vector<int> cell_items_;
};

struct AssociationStats {
  int64_t num_points = 0;
  int64_t num_associated = 0;
  int64_t num_rejected = 0;    // no visible segment of the class within the gate and z range
  int64_t num_changed = 0;     // associations that differ from the previous round
  double mean_distance = 0.0;  // over associated points, metres
};

// For each point i (frame[i], p_in_cam[i]) under `poses` (N, 7 flat), the associated segment or
// -1. `previous` (may be empty) is used to count changes.
std::vector<int> AssociatePoints(const SegmentIndex& index, const ArrayRef<int32_t>& frame,
                                 const ArrayRef<double>& p_in_cam, const double* poses,
                                 const std::vector<int>& previous, AssociationStats* stats);

}  // namespace bimcap

#endif  // BIMCAP_ASSOCIATION_H_
