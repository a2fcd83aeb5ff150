// The paper's proposal for automatic one-shot referencing (Puljiz et al. 2019, Sec. VI), as a
// baseline: slide a box of the robot's bounding-box size over the scene in steps of 0.2 of its
// side, drop boxes with too few points, describe each remaining box by SHOT (Tombari et al.
// 2010; the paper found it picked the right box every time, OUR-CVFH about 70 %), keep the box
// whose descriptor is nearest the model's, and run ICP from its centre at four yaws 90 degrees
// apart, keeping the best. The yaw is unknown, so the box is the model's box turned to the
// world's axes (its larger horizontal side both ways).
#include <fmt/format.h>
#include <pcl/features/shot.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "arref/baselines/baselines.h"
#include "pcl_cloud.h"
#include "arref/scene/metrics.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"

namespace arref {
namespace {

using PointN = pcl::PointNormal;
using CloudN = pcl::PointCloud<PointN>;


// One SHOT descriptor for each centre, over the surface points within radius of it.
pcl::PointCloud<pcl::SHOT352> Shot(const CloudN::Ptr& surface, const std::vector<Vec3f>& centres, double radius) {
  auto keypoints = pcl::make_shared<CloudN>();
  for (const Vec3f& c : centres) {
    PointN p;
    p.getVector3fMap() = c;
    p.getNormalVector3fMap() = Vec3f::UnitZ();
    keypoints->push_back(p);
  }
  pcl::SHOTEstimation<PointN, PointN, pcl::SHOT352> shot;
  shot.setInputCloud(keypoints);
  shot.setSearchSurface(surface);
  shot.setInputNormals(surface);
  shot.setSearchMethod(pcl::make_shared<pcl::search::KdTree<PointN>>());
  shot.setRadiusSearch(radius);
  pcl::PointCloud<pcl::SHOT352> out;
  shot.compute(out);
  return out;
}

double Distance(const pcl::SHOT352& a, const pcl::SHOT352& b) {
  double d = 0;
  for (int i = 0; i < 352; ++i) d += (a.descriptor[i] - b.descriptor[i]) * (a.descriptor[i] - b.descriptor[i]);
  return std::sqrt(d);
}

bool Finite(const pcl::SHOT352& s) { return std::isfinite(s.descriptor[0]) && std::isfinite(s.rf[0]); }

// Points per box of `size` at every step of the grid over `box` (an integral of cell counts).
struct BoxCounts {
  Vec3 origin, step;
  Eigen::Vector3i cells;  // grid cells per axis
  int span = 5;           // cells per box side
  std::vector<int> integral;  // (cells + 1)^3 prefix sums
  int At(int x, int y, int z) const {
    return integral[(static_cast<std::size_t>(z) * static_cast<std::size_t>(cells.y() + 1) + static_cast<std::size_t>(y)) *
                        static_cast<std::size_t>(cells.x() + 1) + static_cast<std::size_t>(x)];
  }
  int Box(int x, int y, int z) const {  // cells [x, x + span) etc.
    const int X = x + span, Y = y + span, Z = z + span;
    return At(X, Y, Z) - At(x, Y, Z) - At(X, y, Z) - At(X, Y, z) + At(x, y, Z) + At(x, Y, z) + At(X, y, z) - At(x, y, z);
  }
};

BoxCounts CountBoxes(const PointCloud& scene, const Vec3& size, double step_fraction) {
  BoxCounts b;
  b.span = std::max(1, static_cast<int>(std::lround(1.0 / step_fraction)));
  b.step = size / b.span;
  const Aabb box = BoundsOf(scene.points);
  b.origin = box.min.cast<double>();
  b.cells = ((box.max - box.min).cast<double>().cwiseQuotient(b.step).array().floor().cast<int>() + 1).matrix();
  b.cells = b.cells.cwiseMax(b.span);
  const Eigen::Vector3i n = b.cells.array() + 1;
  std::vector<int> count(static_cast<std::size_t>(n.prod()), 0);
  auto index = [&](int x, int y, int z) {
    return (static_cast<std::size_t>(z) * static_cast<std::size_t>(n.y()) + static_cast<std::size_t>(y)) * static_cast<std::size_t>(n.x()) +
           static_cast<std::size_t>(x);
  };
  for (const Vec3f& p : scene.points) {
    const Eigen::Vector3i c = ((p.cast<double>() - b.origin).cwiseQuotient(b.step).array().floor().cast<int>()).matrix().cwiseMin(b.cells - Eigen::Vector3i::Ones());
    ++count[index(c.x() + 1, c.y() + 1, c.z() + 1)];
  }
  for (int z = 1; z < n.z(); ++z)
    for (int y = 1; y < n.y(); ++y)
      for (int x = 1; x < n.x(); ++x)
        count[index(x, y, z)] += count[index(x - 1, y, z)] + count[index(x, y - 1, z)] + count[index(x, y, z - 1)] -
                                 count[index(x - 1, y - 1, z)] - count[index(x - 1, y, z - 1)] - count[index(x, y - 1, z - 1)] +
                                 count[index(x - 1, y - 1, z - 1)];
  b.integral = std::move(count);
  return b;
}

}  // namespace

Result<RegistrationOutput> RegisterSlidingBoxShot(const PointCloud& model_base, const PointCloud& scene_world,
                                                  const SlidingBoxParams& params, const IcpParams& icp) {
  if (!(params.step_fraction > 0 && params.step_fraction <= 1) || !(params.leaf_m > 0) || params.icp_yaws < 1)
    return Status::InvalidArgument("sliding-box-shot: step_fraction in (0, 1], leaf_m > 0 and icp_yaws >= 1 needed");
  if (!model_base.has_normals() || !scene_world.has_normals())
    return Status::FailedPrecondition("sliding-box-shot needs normals on model and scene points");
  const PointCloud model = VoxelDownsample(model_base, params.leaf_m);
  const PointCloud scene = VoxelDownsample(scene_world, params.leaf_m);
  if (model.size() < 10 || scene.size() < 10) return Status::FailedPrecondition("sliding-box-shot: too few points");
  const Aabb model_box = BoundsOf(model.points);
  const Vec3 extent = (model_box.max - model_box.min).cast<double>();
  const double side = std::max(extent.x(), extent.y());
  const Vec3 size(side, side, extent.z());
  const Vec3 model_centre = (0.5 * (model_box.min + model_box.max)).cast<double>();

  RegistrationOutput out;
  const BoxCounts counts = CountBoxes(scene, size, params.step_fraction);
  const int min_points = static_cast<int>(params.min_points_fraction * static_cast<double>(model.size()));
  std::vector<Vec3f> centres;
  for (int z = 0; z + counts.span <= counts.cells.z(); ++z)
    for (int y = 0; y + counts.span <= counts.cells.y(); ++y)
      for (int x = 0; x + counts.span <= counts.cells.x(); ++x)
        if (counts.Box(x, y, z) >= min_points)
          centres.push_back((counts.origin + counts.step.cwiseProduct(Vec3(x, y, z)) + 0.5 * size).cast<float>());
  out.stages.push_back(fmt::format("boxes-{}", centres.size()));
  if (centres.empty()) return Status::FailedPrecondition("sliding-box-shot: no box holds enough points for the robot");
  const double radius = 0.5 * size.norm();
  const pcl::PointCloud<pcl::SHOT352> model_shot = Shot(ToPclUnitNormals(model), {model_centre.cast<float>()}, radius);
  const pcl::PointCloud<pcl::SHOT352> box_shots = Shot(ToPclUnitNormals(scene), centres, radius);
  if (model_shot.empty() || !Finite(model_shot[0])) return Status::FailedPrecondition("sliding-box-shot: no SHOT descriptor of the model");
  std::size_t best = centres.size();
  double best_d = std::numeric_limits<double>::max();
  for (std::size_t i = 0; i < box_shots.size(); ++i) {
    if (!Finite(box_shots[i])) continue;
    const double d = Distance(box_shots[i], model_shot[0]);
    if (d < best_d) best_d = d, best = i;
  }
  if (best == centres.size()) return Status::FailedPrecondition("sliding-box-shot: no box had a SHOT descriptor");
  out.stages.push_back("shot");

  // ICP from the best box's centre at each yaw, against the scene round it.
  const Vec3 centre = centres[best].cast<double>();
  PointCloud near;
  for (std::size_t i = 0; i < scene.size(); ++i)
    if ((scene.points[i].cast<double>() - centre).norm() <= 1.5 * radius) {
      near.points.push_back(scene.points[i]);
      near.normals.push_back(scene.normals[i]);
    }
  const PointIndex index(near.points);
  double best_fit = -1;
  for (int k = 0; k < params.icp_yaws; ++k) {
    const double yaw = 2 * std::numbers::pi * k / params.icp_yaws;
    const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
    const Vec3 t = centre - R * model_centre;
    ARREF_ASSIGN_OR_RETURN(const RegistrationOutput fit, RegisterPclIcp(model, near, MakeYawPose(t.x(), t.y(), t.z(), yaw), icp, false));
    const double score = MeasureFit(model.points, fit.T_world_base, index, 0.02).inlier_fraction;
    out.iterations += fit.iterations;
    if (score > best_fit) {
      best_fit = score;
      out.T_world_base = fit.T_world_base;
      out.converged = fit.converged;
    }
  }
  out.stages.push_back(fmt::format("pcl-icp-x{}", params.icp_yaws));
  out.score = best_fit;  // margin stays negative: no alternative is compared, so never OK
  out.hypotheses = params.icp_yaws;
  return out;
}

}  // namespace arref
