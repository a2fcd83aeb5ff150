// Nearest-neighbour queries over a fixed point set (a nanoflann k-d tree behind a small API).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "arref/base/geometry.h"

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
  // Every point closer than sqrt(max_sq_dist) into out, in no particular order; *count says how
  // many. False, with out incomplete, when there are more than out.size() of them.
  bool AllWithin(const Vec3f& query, float max_sq_dist, std::span<std::uint32_t> out, std::size_t* count) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Nearest-neighbour search for a query that moves a little from one call to the next, as an ICP
// source point does from one iteration to the next: the same answers as
// PointIndex::NearestWithin, mostly without the tree. One per query point, not shared between
// threads.
class MovingNearest {
 public:
  bool NearestWithin(const PointIndex& index, const Vec3f& query, float max_sq_dist, std::uint32_t* i, float* sq_dist);

 private:
  enum class Answer { kFound, kNone, kUnknown };
  Answer FromKept(const std::vector<Vec3f>& points, const Vec3f& query, float max_sq_dist, std::uint32_t* i,
                  float* sq_dist) const;

  static constexpr std::uint32_t kNone = ~std::uint32_t{0};
  static constexpr std::size_t kCapacity = 32;
  std::uint32_t last_ = kNone;  // the last call's answer
  // When there were at most kCapacity of them, every point within radius_ of centre_, the
  // query's position at the last search of the tree.
  Vec3f centre_ = Vec3f::Zero();
  float radius_ = -1.0f;  // < 0: nothing kept
  std::uint32_t count_ = 0;
  std::array<std::uint32_t, kCapacity> kept_;
};

}  // namespace arref
