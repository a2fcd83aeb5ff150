// Pair extraction (Super4PCS Sec. 4): all pairs of Q at distance d +- delta. 4PCS tests all
// n^2 pairs; Super4PCS intersects the sphere of radius d with a subdivision of space, so each
// point visits only the cells the shell passes through and the cost is about linear in n plus
// the output.
#include <algorithm>
#include <numeric>

#include "super4pcs.h"

namespace arref::super4pcs {
namespace {

constexpr std::uint32_t kLeafSize = 8;

// Squared distances from p to the nearest and the farthest point of a box.
void BoxDistances(const Vec3f& p, const Aabb& box, float* near2, float* far2) {
  const Vec3f nearest = p.cwiseMax(box.min).cwiseMin(box.max);
  const Vec3f farthest = (p - box.min).cwiseAbs().cwiseMax((p - box.max).cwiseAbs());
  *near2 = (nearest - p).squaredNorm();
  *far2 = farthest.squaredNorm();
}

}  // namespace

PairExtractor::PairExtractor(const std::vector<Vec3f>& Q) : Q_(Q), order_(Q.size()) {
  std::iota(order_.begin(), order_.end(), 0u);
  nodes_.reserve(2 * Q.size() / kLeafSize + 2);
  if (!Q.empty()) Build(0, static_cast<std::uint32_t>(Q.size()));
}

std::int32_t PairExtractor::Build(std::uint32_t begin, std::uint32_t end) {
  const auto id = static_cast<std::int32_t>(nodes_.size());
  nodes_.push_back({});
  Aabb box;
  for (std::uint32_t k = begin; k < end; ++k) box.Extend(Q_[order_[k]]);
  nodes_[id].box = box;
  nodes_[id].begin = begin;
  nodes_[id].end = end;
  if (end - begin <= kLeafSize) return id;
  int axis;
  (box.max - box.min).maxCoeff(&axis);
  const std::uint32_t mid = begin + (end - begin) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                   [&](std::uint32_t a, std::uint32_t b) { return Q_[a][axis] < Q_[b][axis]; });
  const std::int32_t left = Build(begin, mid);
  const std::int32_t right = Build(mid, end);
  nodes_[id].left = left;
  nodes_[id].right = right;
  return id;
}

void PairExtractor::Query(std::int32_t id, std::uint32_t i, float lo2, float hi2, std::vector<Pair>* out) const {
  const Node& node = nodes_[id];
  float near2, far2;
  BoxDistances(Q_[i], node.box, &near2, &far2);
  if (near2 > hi2 || far2 < lo2) return;  // the shell misses this box
  if (node.left < 0) {
    for (std::uint32_t k = node.begin; k < node.end; ++k) {
      const std::uint32_t j = order_[k];
      const float d2 = (Q_[j] - Q_[i]).squaredNorm();
      // Each unordered pair is met from both ends: that yields both orders, which the
      // congruent-set search needs (the base's ratios are not symmetric).
      if (j != i && d2 >= lo2 && d2 <= hi2) out->push_back({i, j});
    }
    return;
  }
  Query(node.left, i, lo2, hi2, out);
  Query(node.right, i, lo2, hi2, out);
}

std::vector<Pair> PairExtractor::Extract(double distance, double delta) const {
  std::vector<Pair> pairs;
  if (nodes_.empty()) return pairs;
  const double lo = std::max(0.0, distance - delta);
  const auto lo2 = static_cast<float>(lo * lo), hi2 = static_cast<float>((distance + delta) * (distance + delta));
  for (std::uint32_t i = 0; i < Q_.size(); ++i) Query(0, i, lo2, hi2, &pairs);
  return pairs;
}

}  // namespace arref::super4pcs
