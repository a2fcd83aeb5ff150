#include "arref/scene/supports.h"

#include <algorithm>
#include <cmath>

namespace arref {
namespace {

// Heights of the up-facing points near the axis.
std::vector<double> UpFacingHeights(const PointCloud& scene, const SupportSearch& s) {
  std::vector<double> z;
  const double r2 = s.radius_m * s.radius_m;
  for (std::size_t i = 0; i < scene.size(); ++i) {
    const Vec3 p = scene.points[i].cast<double>();
    if ((p - s.centre).head<2>().squaredNorm() > r2 || scene.normals[i].z() < s.min_up_cos) continue;
    z.push_back(p.z());
  }
  return z;
}

}  // namespace

std::vector<Support> FindSupports(const PointCloud& scene_world, const SupportSearch& search) {
  if (!scene_world.has_normals() || !(search.bin_m > 0)) return {};
  const std::vector<double> z = UpFacingHeights(scene_world, search);
  if (z.empty()) return {};
  const auto [lo, hi] = std::minmax_element(z.begin(), z.end());
  const std::size_t bins = static_cast<std::size_t>((*hi - *lo) / search.bin_m) + 1;
  std::vector<std::size_t> count(bins, 0);
  std::vector<double> sum(bins, 0.0);
  for (double v : z) {
    const auto b = static_cast<std::size_t>((v - *lo) / search.bin_m);
    ++count[b];
    sum[b] += v;
  }
  // A peak is a bin holding more than either neighbour; its height is the mean of its points and
  // its neighbours' (a surface's noise spreads it over two or three bins).
  const auto at = [&](std::size_t b, int d) -> std::size_t {
    const long i = static_cast<long>(b) + d;
    return i < 0 || i >= static_cast<long>(bins) ? 0 : count[static_cast<std::size_t>(i)];
  };
  const auto min_points = static_cast<std::size_t>(std::ceil(search.min_share * static_cast<double>(z.size())));
  std::vector<Support> out;
  for (std::size_t b = 0; b < bins; ++b) {
    if (count[b] < std::max<std::size_t>(min_points, 3) || count[b] < at(b, -1) || count[b] <= at(b, 1)) continue;
    double s = sum[b];
    std::size_t n = count[b];
    for (int d : {-1, 1}) {
      const long i = static_cast<long>(b) + d;
      if (i < 0 || i >= static_cast<long>(bins)) continue;
      s += sum[static_cast<std::size_t>(i)];
      n += count[static_cast<std::size_t>(i)];
    }
    out.push_back({s / static_cast<double>(n), n});
  }
  std::stable_sort(out.begin(), out.end(), [](const Support& a, const Support& b) { return a.points > b.points; });
  if (out.size() > search.max_supports) out.resize(search.max_supports);
  return out;
}

}  // namespace arref
