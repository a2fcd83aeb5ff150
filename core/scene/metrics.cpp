#include "arref/scene/metrics.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <cmath>
#include <numbers>

namespace arref {

FitQuality MeasureFit(const std::vector<Vec3f>& model_base, const Iso3& T_world_base, const PointIndex& scene_world,
                      double inlier_threshold_m) {
  FitQuality fit;
  fit.model_points = model_base.size();
  if (model_base.empty() || scene_world.size() == 0) return fit;
  const Eigen::Isometry3f T = T_world_base.cast<float>();
  const float inlier_sq = static_cast<float>(inlier_threshold_m * inlier_threshold_m);
  struct Sum { double sq = 0; std::size_t inliers = 0; };
  const Sum total = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, model_base.size(), 1024), Sum{},
      [&](const tbb::blocked_range<std::size_t>& r, Sum s) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          std::uint32_t index;
          float sq;
          scene_world.Nearest(T * model_base[i], &index, &sq);
          s.sq += sq;
          s.inliers += sq <= inlier_sq;
        }
        return s;
      },
      [](Sum a, const Sum& b) { a.sq += b.sq; a.inliers += b.inliers; return a; });
  fit.rms_m = std::sqrt(total.sq / static_cast<double>(model_base.size()));
  fit.inlier_fraction = static_cast<double>(total.inliers) / static_cast<double>(model_base.size());
  return fit;
}

PoseError ComparePoses(const Iso3& T_est, const Iso3& T_true, const std::vector<Vec3f>& model_points) {
  PoseError e;
  const Vec3 dt = T_est.translation() - T_true.translation();
  e.translation_m = dt.norm();
  e.vertical_m = dt.z();
  e.horizontal_m = dt.head<2>().norm();
  const Eigen::AngleAxisd delta(T_true.rotation().transpose() * T_est.rotation());
  e.rotation_deg = std::abs(delta.angle()) * 180.0 / std::numbers::pi;
  if (model_points.empty()) return e;
  double sum = 0;
  for (const auto& p : model_points) {
    const Vec3 x = p.cast<double>();
    sum += (T_est * x - T_true * x).norm();
  }
  e.add_m = sum / static_cast<double>(model_points.size());
  return e;
}

}  // namespace arref
