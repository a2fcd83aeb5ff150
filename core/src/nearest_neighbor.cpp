#include "arref/nearest_neighbor.h"

#include <nanoflann.hpp>

namespace arref {

struct PointIndex::Impl {
  struct Adaptor {
    const std::vector<Vec3f>* points;
    std::size_t kdtree_get_point_count() const { return points->size(); }
    float kdtree_get_pt(std::size_t i, std::size_t dim) const { return (*points)[i][static_cast<int>(dim)]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const { return false; }
  };
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Adaptor>, Adaptor, 3, std::uint32_t>;

  explicit Impl(std::vector<Vec3f> p)
      : points(std::move(p)), adaptor{&points}, tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16)) {}  // builds it
  std::vector<Vec3f> points;
  Adaptor adaptor;
  Tree tree;
};

PointIndex::PointIndex(std::vector<Vec3f> points) : impl_(std::make_unique<Impl>(std::move(points))) {}
PointIndex::PointIndex(PointIndex&&) noexcept = default;
PointIndex& PointIndex::operator=(PointIndex&&) noexcept = default;
PointIndex::~PointIndex() = default;

std::size_t PointIndex::size() const { return impl_->points.size(); }
const std::vector<Vec3f>& PointIndex::points() const { return impl_->points; }

bool PointIndex::Nearest(const Vec3f& query, std::uint32_t* index, float* sq_dist) const {
  if (impl_->points.empty()) return false;
  nanoflann::KNNResultSet<float, std::uint32_t> result(1);
  result.init(index, sq_dist);
  impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  return true;
}

namespace {
// A nanoflann result set that starts with a finite worst distance.
class BoundedNearest {
 public:
  explicit BoundedNearest(float max_sq) : worst_(max_sq) {}
  bool full() const { return true; }
  bool addPoint(float sq, std::uint32_t index) {
    if (sq < worst_) {
      worst_ = sq;
      index_ = index;
      found_ = true;
    }
    return true;
  }
  float worstDist() const { return worst_; }
  bool found() const { return found_; }
  std::uint32_t index() const { return index_; }

 private:
  float worst_;
  std::uint32_t index_ = 0;
  bool found_ = false;
};
// A nanoflann result set that ends the search at the first point within the bound.
class AnyWithinBound {
 public:
  explicit AnyWithinBound(float max_sq) : bound_(max_sq) {}
  bool full() const { return true; }
  bool addPoint(float sq, std::uint32_t) {
    found_ = found_ || sq < bound_;
    return !found_;  // false: stop searching
  }
  float worstDist() const { return bound_; }
  bool found() const { return found_; }

 private:
  float bound_;
  bool found_ = false;
};
}  // namespace

bool PointIndex::AnyWithin(const Vec3f& query, float max_sq_dist) const {
  if (impl_->points.empty()) return false;
  AnyWithinBound result(max_sq_dist);
  impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  return result.found();
}

bool PointIndex::NearestWithin(const Vec3f& query, float max_sq_dist, std::uint32_t* index, float* sq_dist) const {
  if (impl_->points.empty()) return false;
  BoundedNearest result(max_sq_dist);
  impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  if (!result.found()) return false;
  *index = result.index();
  *sq_dist = result.worstDist();
  return true;
}

}  // namespace arref
