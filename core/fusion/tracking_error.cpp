#include "arref/fusion/tracking_error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <limits>
#include <numbers>

namespace arref {
namespace {

// An eye faces a point when it lies more than ~6 degrees above the point's tangent plane.
constexpr double kFacingCos = 0.1;

// Variance along the unit normal n that one view from eye e leaves at point p: the position
// error along n, plus the orientation error w about the eye: (w x d) . n = w . (d x n).
double ViewVariance(const Vec3& p, const Vec3& n, const Vec3& e, double var_position, double var_orientation) {
  return var_position + var_orientation * (p - e).cross(n).squaredNorm();
}

// Point i's weight, 0 when no eye faces it.
float Weight(const PointCloud& surface, std::size_t i, const std::vector<Vec3>& eyes, double var_position,
             double var_orientation) {
  const Vec3 p = surface.points[i].cast<double>(), n = surface.normals[i].cast<double>();
  double sum = 0;
  int views = 0;
  for (const Vec3& e : eyes) {
    const Vec3 d = e - p;
    if (n.dot(d) < kFacingCos * d.norm()) continue;
    sum += ViewVariance(p, n, e, var_position, var_orientation);
    ++views;
  }
  // Independent views averaged: the variance of their mean is sum / views^2.
  return views > 0 ? static_cast<float>(var_position * views * views / sum) : 0.0f;
}

}  // namespace

std::vector<float> TrackingErrorWeights(const PointCloud& surface, const std::vector<Vec3>& eyes,
                                        const TrackingError& error) {
  const double var_position = error.position_m * error.position_m;
  const double rad = error.orientation_deg * std::numbers::pi / 180;
  const double var_orientation = rad * rad;
  if (eyes.empty() || !surface.has_normals() || !(var_position > 0)) return {};
  std::vector<float> weights(surface.size(), 0.0f);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, surface.size(), 256), [&](const auto& range) {
    for (std::size_t i = range.begin(); i < range.end(); ++i) weights[i] = Weight(surface, i, eyes, var_position, var_orientation);
  });
  float smallest = std::numeric_limits<float>::max();
  for (float w : weights)
    if (w > 0) smallest = std::min(smallest, w);
  if (smallest == std::numeric_limits<float>::max()) return {};  // no eye faces any point
  for (float& w : weights)
    if (w == 0) w = smallest;
  return weights;
}

}  // namespace arref
