#include "arref/scene/sampling.h"

#include <algorithm>
#include <numeric>
#include <random>
#include <tuple>
#include <unordered_map>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace arref {

// Area-weighted triangle choice by binary search in the cumulative area, then a uniform point
// in the triangle by the square-root parameterisation (Osada et al., "Shape distributions",
// ACM TOG 2002, eq. 1): p = (1-sqrt(r1)) a + sqrt(r1)(1-r2) b + sqrt(r1) r2 c.
// The areas and the points are computed in parallel; the running sum and the random draws stay
// in one sequence, so a seed gives the same cloud bit for bit on any number of threads.
PointCloud SampleSurface(const TriangleMesh& mesh, std::size_t n, std::uint64_t seed) {
  PointCloud cloud;
  if (mesh.triangles.empty() || n == 0) return cloud;
  std::vector<double> cumulative(mesh.triangles.size());  // each triangle's area, then their running sum
  std::vector<Vec3f> normals(mesh.triangles.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.triangles.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto& t = mesh.triangles[i];
      const Vec3f cross = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
      const float norm = cross.norm();
      cumulative[i] = 0.5 * norm;
      normals[i] = norm > 0 ? Vec3f(cross / norm) : Vec3f::UnitZ();
    }
  });
  double total = 0.0;
  for (double& c : cumulative) c = total += c;
  if (total <= 0.0) return cloud;
  // Per point: the triangle pick, sqrt(r1) and r2, drawn in that order.
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<double> draws(3 * n);
  for (double& d : draws) d = uniform(rng);
  // Where upper_bound's answer lies for picks in each of `buckets` equal slices of [0, total]:
  // the search then covers a slice's few triangles instead of the whole mesh (same answer).
  const std::size_t buckets = std::max<std::size_t>(1, cumulative.size() / 4);
  const auto lower = [&](std::size_t b) { return total * static_cast<double>(b) / static_cast<double>(buckets); };
  std::vector<std::size_t> first(buckets + 1);  // the first triangle whose running sum exceeds the slice's lower end
  for (std::size_t b = 0, i = 0; b <= buckets; ++b) {
    while (i < cumulative.size() && cumulative[i] <= lower(b)) ++i;
    first[b] = i;
  }
  cloud.points.resize(n);
  cloud.normals.resize(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      const double pick = draws[3 * k] * total;
      auto b = std::min(buckets - 1, static_cast<std::size_t>(pick / total * static_cast<double>(buckets)));
      while (b > 0 && pick < lower(b)) --b;  // rounding may put the pick one slice off
      while (b + 1 < buckets && pick >= lower(b + 1)) ++b;
      // The answer lies in [first[b], first[b + 1]]; when it is the last, upper_bound returns end.
      const auto i = static_cast<std::size_t>(std::min<std::ptrdiff_t>(
          std::upper_bound(cumulative.begin() + static_cast<std::ptrdiff_t>(first[b]),
                           cumulative.begin() + static_cast<std::ptrdiff_t>(first[b + 1]), pick) -
              cumulative.begin(),
          static_cast<std::ptrdiff_t>(cumulative.size()) - 1));
      const auto& t = mesh.triangles[i];
      const float s = static_cast<float>(std::sqrt(draws[3 * k + 1]));
      const float r2 = static_cast<float>(draws[3 * k + 2]);
      cloud.points[k] = (1 - s) * mesh.vertices[t[0]] + s * (1 - r2) * mesh.vertices[t[1]] + s * r2 * mesh.vertices[t[2]];
      cloud.normals[k] = normals[i];
    }
  });
  return cloud;
}

PointCloud SpatiallyOrdered(const PointCloud& cloud, double cell_m) {
  const float inv = static_cast<float>(1.0 / cell_m);
  std::vector<std::tuple<int, int, int>> cell(cloud.size());  // computed once, not per comparison
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3i k = (cloud.points[i] * inv).array().floor().cast<int>();
    cell[i] = std::tuple(k.z(), k.y(), k.x());
  }
  std::vector<std::uint32_t> order(cloud.size());
  std::iota(order.begin(), order.end(), 0u);
  std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return cell[a] < cell[b]; });
  return cloud.Subset(order);
}

PointCloud Thinned(const PointCloud& cloud, std::size_t limit) {
  if (limit == 0) return cloud;
  std::vector<std::uint32_t> keep;
  const std::size_t stride = std::max<std::size_t>(1, (cloud.size() + limit - 1) / limit);
  for (std::size_t i = 0; i < cloud.size(); i += stride) keep.push_back(static_cast<std::uint32_t>(i));
  return SpatiallyOrdered(cloud.Subset(keep));
}

std::uint64_t CellKey(const Vec3f& p, double cell_m) {
  auto axis = [&](float v) { return static_cast<std::uint64_t>(std::floor(v / cell_m) + (1 << 20)) & 0x1FFFFF; };
  return axis(p.x()) | axis(p.y()) << 21 | axis(p.z()) << 42;
}

PointCloud VoxelDownsample(const PointCloud& cloud, double leaf_m) {
  if (leaf_m <= 0.0 || cloud.empty()) return cloud;
  struct Cell { Vec3f sum = Vec3f::Zero(); Vec3f normal = Vec3f::Zero(); int count = 0; };
  std::unordered_map<std::uint64_t, Cell> cells;
  std::vector<std::uint64_t> order;  // first-seen order keeps the output deterministic
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    auto [it, inserted] = cells.try_emplace(CellKey(cloud.points[i], leaf_m));
    if (inserted) order.push_back(it->first);
    it->second.sum += cloud.points[i];
    if (cloud.has_normals()) it->second.normal += cloud.normals[i];
    ++it->second.count;
  }
  PointCloud out;
  for (auto key : order) {
    const Cell& c = cells[key];
    out.points.push_back(c.sum / static_cast<float>(c.count));
    if (cloud.has_normals()) out.normals.push_back(c.normal.normalized());
  }
  return out;
}

}  // namespace arref
