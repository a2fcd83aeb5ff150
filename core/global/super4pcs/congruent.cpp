// Congruent-set extraction (Super4PCS Sec. 5). 4PCS matches intermediate points only, which
// accepts every affine image of the base; Super4PCS also requires the angle between the two
// pair directions to equal the base's, a rigid invariant that needs no normals. Intermediate
// points are indexed in a grid of cell delta, so each query touches 27 cells.
#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "arref/scene/sampling.h"
#include "super4pcs.h"

namespace arref::super4pcs {

std::vector<Congruent> FindCongruentSets(const std::vector<Vec3f>& Q, const Base& base, const std::vector<Pair>& pairs1,
                                         const std::vector<Pair>& pairs2, double delta, double angle_tolerance_rad,
                                         std::size_t max_sets) {
  const float cell = static_cast<float>(delta);
  const float delta2 = cell * cell;
  // Eq. (1) of 4PCS: e1 = q_i + r1 (q_j - q_i) for every pair of the first set.
  std::vector<Vec3f> e1(pairs1.size());
  std::vector<Vec3f> dir1(pairs1.size());
  std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> grid;  // by CellKey (sampling.h)
  grid.reserve(pairs1.size());
  for (std::uint32_t k = 0; k < pairs1.size(); ++k) {
    const Vec3f& qi = Q[pairs1[k][0]];
    const Vec3f& qj = Q[pairs1[k][1]];
    e1[k] = qi + base.r1 * (qj - qi);
    dir1[k] = (qj - qi).normalized();
    grid[CellKey(e1[k], cell)].push_back(k);
  }
  const float base_angle = std::acos(std::clamp(base.cos_angle, -1.0f, 1.0f));
  const auto tolerance = static_cast<float>(angle_tolerance_rad);
  std::vector<Congruent> sets;
  for (const auto& p2 : pairs2) {
    const Vec3f& qk = Q[p2[0]];
    const Vec3f& ql = Q[p2[1]];
    const Vec3f e2 = qk + base.r2 * (ql - qk);
    const Vec3f dir2 = (ql - qk).normalized();
    const Vec3f c = e2 / cell;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = grid.find(CellKey(Vec3f((c.x() + dx) * cell, (c.y() + dy) * cell, (c.z() + dz) * cell), cell));
          if (it == grid.end()) continue;
          for (std::uint32_t k : it->second) {
            if ((e1[k] - e2).squaredNorm() > delta2) continue;
            const float angle = std::acos(std::clamp(dir1[k].dot(dir2), -1.0f, 1.0f));
            if (std::abs(angle - base_angle) > tolerance) continue;
            const Pair& p1 = pairs1[k];
            // Shared points cannot be a rigid image of four distinct base points.
            if (p1[0] == p2[0] || p1[0] == p2[1] || p1[1] == p2[0] || p1[1] == p2[1]) continue;
            sets.push_back({p1[0], p1[1], p2[0], p2[1]});
            if (sets.size() >= max_sets) return sets;
          }
        }
  }
  return sets;
}

}  // namespace arref::super4pcs
