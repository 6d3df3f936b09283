#include "bimcap/pose.h"

#include <ceres/product_manifold.h>
#include <ceres/sphere_manifold.h>

namespace bimcap {

std::unique_ptr<ceres::Manifold> CreatePoseManifold(RefineMode mode) {
  switch (mode) {
    case RefineMode::kRotation:
      return std::make_unique<
          ceres::ProductManifold<ceres::SubsetManifold, ceres::EigenQuaternionManifold>>(
          ceres::SubsetManifold(3, {0, 1, 2}), ceres::EigenQuaternionManifold());
    case RefineMode::kTranslation:
      return std::make_unique<
          ceres::ProductManifold<ceres::EuclideanManifold<3>, ceres::SubsetManifold>>(
          ceres::EuclideanManifold<3>(), ceres::SubsetManifold(4, {0, 1, 2, 3}));
    case RefineMode::kFull:
    default:
      return std::make_unique<
          ceres::ProductManifold<ceres::EuclideanManifold<3>, ceres::EigenQuaternionManifold>>();
  }
}

bool IsFullPoseManifold(const ceres::Manifold* manifold) {
  return dynamic_cast<const ceres::ProductManifold<ceres::EuclideanManifold<3>,
                                                   ceres::EigenQuaternionManifold>*>(manifold) !=
         nullptr;
}

std::unique_ptr<ceres::Manifold> CreatePlaneManifold() {
  return std::make_unique<
      ceres::ProductManifold<ceres::SphereManifold<3>, ceres::EuclideanManifold<1>>>();
}

}  // namespace bimcap
