// The paper's optional Moving Least Squares resampling, through PCL. PCL headers stay in
// this file: they are slow to compile.
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/surface/mls.h>

#include "arref/baselines/baselines.h"

namespace arref {

Result<PointCloud> MlsResample(const PointCloud& cloud, const MlsOptions& options) {
  if (!(options.search_radius_m > 0)) return Status::InvalidArgument("MLS search radius must be > 0");
  if (options.polynomial_order < 0 || options.polynomial_order > 4)
    return Status::InvalidArgument("MLS polynomial order must be in [0, 4]");
  auto input = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  input->reserve(cloud.size());
  for (const auto& p : cloud.points) input->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));

  pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointNormal> mls;
  mls.setInputCloud(input);
  mls.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  mls.setSearchRadius(options.search_radius_m);
  mls.setPolynomialOrder(options.polynomial_order);
  mls.setComputeNormals(true);
  using U = MlsOptions::Upsampling;
  using Pcl = pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointNormal>;
  switch (options.upsampling) {
    case U::kNone: mls.setUpsamplingMethod(Pcl::NONE); break;
    case U::kSampleLocalPlane:
      mls.setUpsamplingMethod(Pcl::SAMPLE_LOCAL_PLANE);
      mls.setUpsamplingRadius(options.upsampling_radius_m);
      mls.setUpsamplingStepSize(options.upsampling_step_m);
      break;
    case U::kRandomUniformDensity:
      mls.setUpsamplingMethod(Pcl::RANDOM_UNIFORM_DENSITY);
      mls.setPointDensity(options.point_density);
      break;
    case U::kVoxelGridDilation:
      mls.setUpsamplingMethod(Pcl::VOXEL_GRID_DILATION);
      mls.setDilationVoxelSize(static_cast<float>(options.dilation_voxel_m));
      break;
  }
  pcl::PointCloud<pcl::PointNormal> output;
  mls.process(output);
  PointCloud out;
  out.points.reserve(output.size());
  out.normals.reserve(output.size());
  for (const auto& p : output) {
    if (!std::isfinite(p.x) || !std::isfinite(p.normal_x)) continue;
    out.points.emplace_back(p.x, p.y, p.z);
    out.normals.emplace_back(p.normal_x, p.normal_y, p.normal_z);
  }
  if (out.empty()) return Status::FailedPrecondition("MLS produced no points (search radius too small for the sampling?)");
  return out;
}

}  // namespace arref
