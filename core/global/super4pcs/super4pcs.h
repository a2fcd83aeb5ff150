// Super4PCS internals (Mellado, Aiger, Mitra: "Super 4PCS: Fast Global Pointcloud
// Registration via Smart Indexing", SGP 2014). P is the cloud the bases come from, Q the
// cloud searched for congruent 4-point sets; the result maps P onto Q.
#pragma once

#include <array>
#include <cstdint>
#include <random>
#include <vector>

#include "arref/base/geometry.h"

namespace arref::super4pcs {

// A coplanar 4-point base {a, b, c, d} of P (4PCS, Aiger et al. 2008, Sec. 3): segments ab and
// cd cross at e = a + r1 (b - a) = c + r2 (d - c). The affine-invariant ratios r1, r2, the
// lengths d1, d2 and the angle between the segments characterise it up to a rigid motion.
struct Base {
  std::array<Vec3f, 4> points;  // a, b, c, d
  float r1 = 0, r2 = 0;
  float d1 = 0, d2 = 0;
  float cos_angle = 0;  // cosine of the angle between (b - a) and (d - c)
};

// Draws a wide, coplanar base from P: three points about `width` apart, the fourth closest to
// their plane, paired so that the segments cross. False when P offers none after `tries`.
bool SelectBase(const std::vector<Vec3f>& P, double width, double delta, std::mt19937_64& rng, Base* base,
                int tries = 50);

// Ordered pairs (i, j), both orders, of Q points with |q_i - q_j| within [d - delta, d + delta].
using Pair = std::array<std::uint32_t, 2>;

// Sec. 4: pair extraction in time about linear in the points and the output. Like the
// paper's recursive subdivision of space intersected with the sphere of radius d, Q is held
// in a hierarchy of boxes (a k-d tree) and a query descends only into boxes that the shell
// [d - delta, d + delta] around the point passes through.
class PairExtractor {
 public:
  explicit PairExtractor(const std::vector<Vec3f>& Q);
  std::vector<Pair> Extract(double distance, double delta) const;

 private:
  struct Node {
    Aabb box;
    std::uint32_t begin = 0, end = 0;  // range of order_
    std::int32_t left = -1, right = -1;
  };
  std::int32_t Build(std::uint32_t begin, std::uint32_t end);
  void Query(std::int32_t node, std::uint32_t i, float lo2, float hi2, std::vector<Pair>* out) const;

  const std::vector<Vec3f>& Q_;
  std::vector<std::uint32_t> order_;
  std::vector<Node> nodes_;
};

// One congruent set: Q indices matching the base's a, b, c, d.
using Congruent = std::array<std::uint32_t, 4>;

// Sec. 5: congruent-set extraction. Each pair of the first set is indexed by its intermediate
// point e1 = q_i + r1 (q_j - q_i); each pair of the second set looks up the e1 within delta of
// its own e2 and keeps those whose direction makes the base's angle with its own (the
// normal-free angle filter that removes most of 4PCS's affine-only matches).
std::vector<Congruent> FindCongruentSets(const std::vector<Vec3f>& Q, const Base& base, const std::vector<Pair>& pairs1,
                                         const std::vector<Pair>& pairs2, double delta, double angle_tolerance_rad,
                                         std::size_t max_sets);

}  // namespace arref::super4pcs
