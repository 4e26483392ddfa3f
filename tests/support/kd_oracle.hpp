// Nearest-point distances by a nanoflann k-d tree: an oracle independent of the project's own
// point searches (the k-NN grid, the voxel hashes), for tests only.
#pragma once

#include <Eigen/Core>
#include <nanoflann.hpp>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>

namespace hc::test {

/// Distances from query points to the nearest of a fixed set of points.
/// @param points 3 × n, any frame and unit (queries in the same); kept by reference, so it must
///        outlive the oracle.
class KdOracle {
 public:
  explicit KdOracle(const Eigen::Matrix3Xd& points)
      : adaptor_{&points}, tree_(std::make_unique<Tree>(3, adaptor_, nanoflann::KDTreeSingleIndexAdaptorParams(16))) {}
  // The tree refers to this object's adaptor: not copyable or movable.
  KdOracle(const KdOracle&) = delete;
  KdOracle& operator=(const KdOracle&) = delete;

  /// Euclidean distance from q to the nearest point, in the points' unit; infinity when there
  /// are no points (so that a test of "near a point" cannot pass on an empty set).
  double nearest(const Eigen::Vector3d& q) const {
    if (adaptor_.p->cols() == 0) return std::numeric_limits<double>::infinity();
    std::uint32_t idx = 0;
    double d2 = 0.0;
    tree_->knnSearch(q.data(), 1, &idx, &d2);
    return std::sqrt(d2);
  }

 private:
  struct Adaptor {
    const Eigen::Matrix3Xd* p;
    std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(p->cols()); }
    double kdtree_get_pt(std::size_t i, int d) const { return (*p)(d, static_cast<Eigen::Index>(i)); }
    template <class B>
    bool kdtree_get_bbox(B&) const {
      return false;
    }
  };
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Adaptor>, Adaptor, 3>;
  Adaptor adaptor_;
  std::unique_ptr<Tree> tree_;
};

}  // namespace hc::test
