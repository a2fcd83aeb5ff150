// The paper's segmentation for global methods (Puljiz et al. 2019, Sec. IV-B): Super4PCS
// needed the robot cut out of the room. RANSAC removes large planes (floor, walls, table
// top), Euclidean clustering splits the rest into objects, the clusters near the seed stay.
#include <fmt/format.h>
#include <pcl/ModelCoefficients.h>
#include <pcl/filters/extract_indices.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>
#include <pcl/segmentation/sac_segmentation.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "global_registration.h"

namespace arref {
namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

Status CheckParams(const SegmentationParams& p) {
  if (!(p.plane_distance_m > 0) || !(p.cluster_tolerance_m > 0) || !(p.seed_radius_m > 0))
    return Status::InvalidArgument("segmentation: plane distance, cluster tolerance and seed radius must be > 0 m");
  if (!(p.min_plane_fraction > 0 && p.min_plane_fraction <= 1))
    return Status::InvalidArgument("segmentation: min plane fraction must be in (0, 1]");
  if (p.max_planes < 0 || !(p.max_extent_ratio > 1))
    return Status::InvalidArgument("segmentation: max planes must be >= 0 and max extent ratio > 1");
  return Status::Ok();
}

// Indices (into `cloud`) of the points left after removing every plane holding at least
// min_plane_fraction of the input.
std::vector<int> RemoveLargePlanes(const Cloud::Ptr& cloud, const SegmentationParams& p) {
  std::vector<int> left(cloud->size());
  for (std::size_t i = 0; i < left.size(); ++i) left[i] = static_cast<int>(i);
  const auto min_inliers = static_cast<std::size_t>(p.min_plane_fraction * static_cast<double>(cloud->size()));
  pcl::SACSegmentation<pcl::PointXYZ> sac;
  sac.setModelType(pcl::SACMODEL_PLANE);
  sac.setMethodType(pcl::SAC_RANSAC);
  sac.setDistanceThreshold(p.plane_distance_m);
  sac.setMaxIterations(200);
  sac.setInputCloud(cloud);
  for (int plane = 0; plane < p.max_planes && left.size() >= min_inliers; ++plane) {
    auto indices = pcl::make_shared<pcl::Indices>(left);
    sac.setIndices(indices);
    pcl::PointIndices inliers;
    pcl::ModelCoefficients coefficients;
    sac.segment(inliers, coefficients);
    if (inliers.indices.size() < min_inliers) break;
    std::vector<char> drop(cloud->size(), 0);
    for (int i : inliers.indices) drop[i] = 1;
    std::erase_if(left, [&](int i) { return drop[i] != 0; });
    spdlog::debug("segmentation: removed a plane of {} points, {} left", inliers.indices.size(), left.size());
  }
  return left;
}

double HorizontalDistance(const pcl::PointXYZ& p, const Vec3& axis_point) {
  return std::hypot(p.x - axis_point.x(), p.y - axis_point.y());
}

// Width of a point set seen from above (z is up in the world and the base frame): twice the
// largest horizontal distance from the centroid, which unlike a bounding box ignores yaw.
double HorizontalWidth(const std::vector<Vec3f>& points) {
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const auto& p : points) centroid += p.head<2>().cast<double>();
  centroid /= static_cast<double>(std::max<std::size_t>(points.size(), 1));
  double radius = 0;
  for (const auto& p : points) radius = std::max(radius, (p.head<2>().cast<double>() - centroid).norm());
  return 2 * radius;
}

}  // namespace

Result<PointCloud> SegmentNearSeed(const PointCloud& scene_world, const Iso3& T_world_seed,
                                   const PointCloud& model_base, const SegmentationParams& params) {
  ARREF_RETURN_IF_ERROR(CheckParams(params));
  auto cloud = pcl::make_shared<Cloud>();
  cloud->reserve(scene_world.size());
  for (const auto& p : scene_world.points) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  const std::vector<int> left = RemoveLargePlanes(cloud, params);

  pcl::EuclideanClusterExtraction<pcl::PointXYZ> clustering;
  clustering.setClusterTolerance(params.cluster_tolerance_m);
  clustering.setMinClusterSize(static_cast<pcl::uindex_t>(params.min_cluster_points));
  clustering.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  clustering.setInputCloud(cloud);
  clustering.setIndices(pcl::make_shared<pcl::Indices>(left));
  std::vector<pcl::PointIndices> clusters;
  clustering.extract(clusters);

  // The cluster nearest to the seed's vertical axis is the robot: clutter beside it must not
  // enter the global search, whose bases would otherwise land on boxes.
  const Vec3 seed = T_world_seed.translation();
  const pcl::PointIndices* nearest = nullptr;
  double nearest_distance = params.seed_radius_m;
  for (const auto& c : clusters)
    for (int i : c.indices)
      if (const double d = HorizontalDistance((*cloud)[i], seed); d <= nearest_distance) nearest_distance = d, nearest = &c;
  if (nearest == nullptr || nearest->indices.size() < 4)
    return Status::FailedPrecondition(fmt::format(
        "segmentation: no cluster within {:.2f} m of the seed after removing planes ({} clusters elsewhere)",
        params.seed_radius_m, clusters.size()));
  std::vector<std::uint32_t> kept(nearest->indices.begin(), nearest->indices.end());

  PointCloud out;
  for (auto i : kept) out.points.push_back(scene_world.points[i]);
  if (scene_world.has_normals())
    for (auto i : kept) out.normals.push_back(scene_world.normals[i]);
  const double width = HorizontalWidth(out.points);
  const double robot_width = HorizontalWidth(model_base.points);
  spdlog::debug("segmentation: {} clusters, kept {} points, {:.2f} m wide (robot {:.2f} m)", clusters.size(), out.size(),
                width, robot_width);
  if (width > params.max_extent_ratio * robot_width)
    return Status::FailedPrecondition(fmt::format(
        "segmentation: the cluster near the seed is {:.2f} m wide, larger than the robot ({:.2f} m): "
        "the robot touches other objects (table?)",
        width, robot_width));
  return out;
}

}  // namespace arref
