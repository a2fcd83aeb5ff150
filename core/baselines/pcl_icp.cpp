// ICP through PCL 1.13, as used by the paper (Puljiz et al. 2019, Sec. III-A).
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/registration/icp.h>

#include "arref/baselines/baselines.h"

namespace arref {
namespace {

// PCL keeps the iteration count protected; the report needs it.
template <typename Base>
class CountingIcp : public Base {
 public:
  int iterations() const { return this->nr_iterations_; }
};

pcl::PointCloud<pcl::PointNormal>::Ptr ToPcl(const PointCloud& cloud) {
  auto out = pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  out->resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    auto& p = (*out)[i];
    p.getVector3fMap() = cloud.points[i];
    p.getNormalVector3fMap() = cloud.has_normals() ? cloud.normals[i] : Vec3f::Zero();
  }
  return out;
}

template <typename Icp>
RegistrationOutput Run(Icp& icp, const PointCloud& model_base, const PointCloud& scene_world,
                       const Iso3& T_world_base_initial, const IcpParams& params) {
  icp.setInputSource(ToPcl(model_base));
  icp.setInputTarget(ToPcl(scene_world));
  icp.setMaxCorrespondenceDistance(params.max_correspondence_m);
  icp.setMaximumIterations(params.max_iterations);
  icp.setTransformationEpsilon(params.transformation_epsilon);
  icp.setEuclideanFitnessEpsilon(params.euclidean_fitness_epsilon);
  pcl::PointCloud<pcl::PointNormal> aligned;
  icp.align(aligned, T_world_base_initial.matrix().cast<float>());
  RegistrationOutput out;
  out.T_world_base.matrix() = icp.getFinalTransformation().template cast<double>();
  // Re-orthonormalise: PCL accumulates the transform in float.
  out.T_world_base.linear() = Quat(out.T_world_base.rotation()).normalized().toRotationMatrix();
  out.iterations = icp.iterations();
  out.converged = icp.hasConverged();
  return out;
}

}  // namespace

Result<RegistrationOutput> RegisterPclIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                          const Iso3& T_world_base_initial, const IcpParams& params,
                                          bool point_to_plane) {
  if (model_base.size() < 3 || scene_world.size() < 3)
    return Status::FailedPrecondition("ICP needs at least 3 model and 3 scene points (have " +
                                      std::to_string(model_base.size()) + " and " + std::to_string(scene_world.size()) + ")");
  if (!(params.max_correspondence_m > 0) || params.max_iterations <= 0)
    return Status::InvalidArgument("ICP needs max correspondence distance > 0 and max iterations > 0");
  if (point_to_plane && (!model_base.has_normals() || !scene_world.has_normals()))
    return Status::FailedPrecondition("point-to-plane ICP needs normals on model and scene");
  RegistrationOutput out;
  if (point_to_plane) {
    CountingIcp<pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal>> icp;
    out = Run(icp, model_base, scene_world, T_world_base_initial, params);
  } else {
    CountingIcp<pcl::IterativeClosestPoint<pcl::PointNormal, pcl::PointNormal>> icp;
    out = Run(icp, model_base, scene_world, T_world_base_initial, params);
  }
  out.stages = {point_to_plane ? "pcl-icp-plane" : "pcl-icp"};
  return out;
}

Result<RegistrationOutput> RegisterPclGicp(const PointCloud& model_base, const PointCloud& scene_world,
                                           const Iso3& T_world_base_initial, const IcpParams& params) {
  if (model_base.size() < 20 || scene_world.size() < 20)
    return Status::FailedPrecondition("GICP needs at least 20 model and 20 scene points for its covariances");
  if (!(params.max_correspondence_m > 0) || params.max_iterations <= 0)
    return Status::InvalidArgument("GICP needs max correspondence distance > 0 and max iterations > 0");
  CountingIcp<pcl::GeneralizedIterativeClosestPoint<pcl::PointNormal, pcl::PointNormal>> gicp;
  RegistrationOutput out = Run(gicp, model_base, scene_world, T_world_base_initial, params);
  out.stages = {"pcl-gicp"};
  return out;
}

}  // namespace arref
