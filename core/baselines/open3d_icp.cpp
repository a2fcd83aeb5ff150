// ICP through Open3D 0.16 (Debian's libopen3d-dev), for the engine comparison. Built only
// when CMake finds Open3D; the registry lists these methods only then.
#include <open3d/geometry/PointCloud.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>

#include "arref/baselines/baselines.h"

namespace arref {
namespace {

open3d::geometry::PointCloud ToOpen3d(const PointCloud& cloud) {
  open3d::geometry::PointCloud out;
  out.points_.reserve(cloud.size());
  for (const auto& p : cloud.points) out.points_.push_back(p.cast<double>());
  if (cloud.has_normals())
    for (const auto& n : cloud.normals) out.normals_.push_back(n.cast<double>());
  return out;
}

}  // namespace

Result<RegistrationOutput> RegisterOpen3dIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                             const Iso3& T_world_base_initial, const IcpParams& params,
                                             bool point_to_plane) {
  namespace reg = open3d::pipelines::registration;
  if (model_base.size() < 3 || scene_world.size() < 3)
    return Status::FailedPrecondition("Open3D ICP needs at least 3 model and 3 scene points");
  if (point_to_plane && !scene_world.has_normals())
    return Status::FailedPrecondition("Open3D point-to-plane ICP needs scene normals");
  const auto source = ToOpen3d(model_base);
  const auto target = ToOpen3d(scene_world);
  const reg::ICPConvergenceCriteria criteria(params.euclidean_fitness_epsilon, params.transformation_epsilon,
                                             params.max_iterations);
  const auto result =
      point_to_plane
          ? reg::RegistrationICP(source, target, params.max_correspondence_m, T_world_base_initial.matrix(),
                                 reg::TransformationEstimationPointToPlane(), criteria)
          : reg::RegistrationICP(source, target, params.max_correspondence_m, T_world_base_initial.matrix(),
                                 reg::TransformationEstimationPointToPoint(false), criteria);
  RegistrationOutput out;
  out.T_world_base.matrix() = result.transformation_;
  out.converged = true;  // Open3D 0.16 reports neither convergence nor the iteration count
  out.stages = {point_to_plane ? "open3d-icp-plane" : "open3d-icp"};
  return out;
}

}  // namespace arref
