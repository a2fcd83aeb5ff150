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

std::size_t PointsBetween(const std::vector<double>& z, double lo, double hi) {
  return static_cast<std::size_t>(std::count_if(z.begin(), z.end(), [&](double v) { return v >= lo && v < hi; }));
}

// The support's height from the points of its peak and its neighbours' bins (a surface's noise
// spreads it over two or three): their median, then the mean of those within a quarter bin of
// it. A plain mean leans up by a millimetre or two, towards the rounded concave corners a
// fused mesh makes where a base or a wall meets the floor (their faces still point up).
double RobustHeight(const std::vector<double>& z, double lo, double hi, double bin) {
  std::vector<double> in;
  for (double v : z)
    if (v >= lo && v < hi) in.push_back(v);
  const auto mid = in.begin() + static_cast<long>(in.size() / 2);
  std::nth_element(in.begin(), mid, in.end());
  const double median = *mid;
  double sum = 0;
  std::size_t n = 0;
  for (double v : in)
    if (std::abs(v - median) <= bin / 4) sum += v, ++n;
  return n ? sum / static_cast<double>(n) : median;
}

}  // namespace

std::vector<Support> FindSupports(const PointCloud& scene_world, const SupportSearch& search) {
  if (!scene_world.has_normals() || !(search.bin_m > 0)) return {};
  const std::vector<double> z = UpFacingHeights(scene_world, search);
  if (z.empty()) return {};
  const auto [lo, hi] = std::minmax_element(z.begin(), z.end());
  const std::size_t bins = static_cast<std::size_t>((*hi - *lo) / search.bin_m) + 1;
  std::vector<std::size_t> count(bins, 0);
  for (double v : z) ++count[static_cast<std::size_t>((v - *lo) / search.bin_m)];
  // A peak is a bin holding more than either neighbour; its height is RobustHeight's.
  const auto at = [&](std::size_t b, int d) -> std::size_t {
    const long i = static_cast<long>(b) + d;
    return i < 0 || i >= static_cast<long>(bins) ? 0 : count[static_cast<std::size_t>(i)];
  };
  const auto min_points = static_cast<std::size_t>(std::ceil(search.min_share * static_cast<double>(z.size())));
  std::vector<Support> out;
  for (std::size_t b = 0; b < bins; ++b) {
    if (count[b] < std::max<std::size_t>(min_points, 3) || count[b] < at(b, -1) || count[b] <= at(b, 1)) continue;
    const double lo_z = *lo + (static_cast<double>(b) - 1) * search.bin_m, hi_z = lo_z + 3 * search.bin_m;
    out.push_back({RobustHeight(z, lo_z, hi_z, search.bin_m), PointsBetween(z, lo_z, hi_z)});
  }
  std::stable_sort(out.begin(), out.end(), [](const Support& a, const Support& b) { return a.points > b.points; });
  if (out.size() > search.max_supports) out.resize(search.max_supports);
  return out;
}

}  // namespace arref
