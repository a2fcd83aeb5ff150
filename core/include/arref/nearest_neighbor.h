// Nearest-neighbour queries over a fixed point set (a nanoflann k-d tree behind a small API).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "arref/geometry.h"

namespace arref {

class PointIndex {
 public:
  explicit PointIndex(std::vector<Vec3f> points);
  PointIndex(PointIndex&&) noexcept;
  PointIndex& operator=(PointIndex&&) noexcept;
  ~PointIndex();

  std::size_t size() const;
  const std::vector<Vec3f>& points() const;
  // False only for an empty index. sq_dist is the squared Euclidean distance.
  bool Nearest(const Vec3f& query, std::uint32_t* index, float* sq_dist) const;
  // The nearest point closer than sqrt(max_sq_dist), or false. Much faster than Nearest when
  // the query is far from every point: the bound prunes the tree from the start.
  bool NearestWithin(const Vec3f& query, float max_sq_dist, std::uint32_t* index, float* sq_dist) const;
  // Whether any point is closer than sqrt(max_sq_dist): NearestWithin's answer, but the search
  // stops at the first such point instead of looking on for the nearest.
  bool AnyWithin(const Vec3f& query, float max_sq_dist) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace arref
