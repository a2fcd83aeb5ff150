#include "arref/scene/nearest_neighbor.h"

#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

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
// A nanoflann result set that collects every point within the bound, up to a capacity; the
// search ends when one more would not fit.
class CollectWithin {
 public:
  CollectWithin(float max_sq, std::span<std::uint32_t> out) : bound_(max_sq), out_(out) {}
  bool full() const { return true; }
  bool addPoint(float sq, std::uint32_t index) {
    if (!(sq < bound_)) return true;
    if (count_ == out_.size()) {
      overflow_ = true;
      return false;
    }
    out_[count_++] = index;
    return true;
  }
  float worstDist() const { return bound_; }
  bool overflow() const { return overflow_; }
  std::size_t count() const { return count_; }

 private:
  float bound_;
  std::span<std::uint32_t> out_;
  std::size_t count_ = 0;
  bool overflow_ = false;
};
}  // namespace

bool PointIndex::AllWithin(const Vec3f& query, float max_sq_dist, std::span<std::uint32_t> out,
                           std::size_t* count) const {
  CollectWithin result(max_sq_dist, out);
  if (!impl_->points.empty()) impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  *count = result.count();
  return !result.overflow();
}

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

namespace {
// The squared distance as nanoflann's L2_Simple_Adaptor sums it, so that ties resolve alike.
float SquaredDistance(const Vec3f& a, const Vec3f& b) {
  float sum = 0.0f;
  for (int k = 0; k < 3; ++k) {
    const float d = a[k] - b[k];
    sum += d * d;
  }
  return sum;
}

// How far a query may move before the tree is searched again (m): only speed depends on it.
constexpr float kSlide = 0.004f;
// Beyond this radius (m) a neighbourhood would hold too many points to be worth keeping.
constexpr float kMaxKeptRadius = 0.1f;
}  // namespace

// A query now at q, delta from the centre, is at least radius - delta from every point that was
// not kept. So the nearest kept point is the nearest of all when it is nearer than that, and
// nothing is within max_sq_dist when radius - delta reaches it and no kept point is within it.
MovingNearest::Answer MovingNearest::FromKept(const std::vector<Vec3f>& points, const Vec3f& query,
                                              float max_sq_dist, std::uint32_t* i, float* sq_dist) const {
  if (radius_ < 0) return Answer::kUnknown;
  // The margin covers float rounding here and in the tree's pruning when it collected them.
  const float reach = (radius_ - (query - centre_).norm()) * (1 - 1e-4f) - 1e-6f;
  if (reach <= 0) return Answer::kUnknown;
  float best = std::numeric_limits<float>::infinity();
  std::uint32_t best_index = kNone;
  for (std::uint32_t k = 0; k < count_; ++k) {
    const float sq = SquaredDistance(query, points[kept_[k]]);
    if (sq < best) best = sq, best_index = kept_[k];
  }
  const float reach_sq = reach * reach;
  if (best < reach_sq) {
    if (!(best < max_sq_dist)) return Answer::kNone;
    *i = best_index, *sq_dist = best;
    return Answer::kFound;
  }
  return reach_sq >= max_sq_dist ? Answer::kNone : Answer::kUnknown;
}

// Otherwise the last answer bounds the tree's search from the start: the nearest point is no
// farther than it (a hair more, so that the old answer itself still counts). The points within
// that bound plus kSlide are kept for the next calls.
bool MovingNearest::NearestWithin(const PointIndex& index, const Vec3f& query, float max_sq_dist, std::uint32_t* i,
                                  float* sq_dist) {
  const std::vector<Vec3f>& points = index.points();
  Answer answer = FromKept(points, query, max_sq_dist, i, sq_dist);
  if (answer == Answer::kUnknown) {
    float bound = max_sq_dist;
    if (last_ != kNone) bound = std::min(bound, 1.0001f * (query - points[last_]).squaredNorm() + 1e-12f);
    const float radius = std::sqrt(bound) + kSlide;
    std::size_t count = 0;
    radius_ = -1.0f;
    if (radius <= kMaxKeptRadius && index.AllWithin(query, radius * radius, kept_, &count)) {
      centre_ = query, radius_ = radius, count_ = static_cast<std::uint32_t>(count);
      answer = FromKept(points, query, max_sq_dist, i, sq_dist);
    }
    if (answer == Answer::kUnknown) answer = index.NearestWithin(query, bound, i, sq_dist) ? Answer::kFound : Answer::kNone;
  }
  last_ = answer == Answer::kFound ? *i : kNone;
  return answer == Answer::kFound;
}

}  // namespace arref
