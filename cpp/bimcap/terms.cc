#include "bimcap/terms.h"

#include <string>

namespace bimcap {

// Each term's spec is defined in its own file in bimcap/terms/.
TermSpec GeometricTerm();      // terms/geometric.cc
TermSpec LandmarkDepthTerm();  // terms/geometric.cc
TermSpec FloorTerm();          // terms/planes.cc
TermSpec CeilingTerm();        // terms/planes.cc
TermSpec WallTerm();           // terms/segments.cc
TermSpec ColumnTerm();         // terms/segments.cc
TermSpec PosePriorTerm();      // terms/pose_prior.cc
TermSpec OdometryTerm();       // terms/odometry.cc

const std::vector<TermSpec>& Terms() {
  // The order is the summary order and the build order: the pose prior anchors only the poses
  // that the terms before it put into the problem.
  static const std::vector<TermSpec> terms = {
      GeometricTerm(), LandmarkDepthTerm(), FloorTerm(),     CeilingTerm(),
      WallTerm(),      ColumnTerm(),        PosePriorTerm(), OdometryTerm(),
  };
  return terms;
}

int NumTerms() { return static_cast<int>(Terms().size()); }

int TermIndex(std::string_view key_or_name) {
  for (int t = 0; t < NumTerms(); ++t) {
    if (key_or_name == Terms()[t].key || key_or_name == Terms()[t].name) return t;
  }
  return -1;
}

const char* TermName(int term) {
  return (term >= 0 && term < NumTerms()) ? Terms()[term].name : "?";
}

}  // namespace bimcap
