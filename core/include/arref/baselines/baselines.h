// The comparison methods, library arref_baselines (built with ARREF_WITH_PCL): the paper's
// ICP through PCL, PCL's Generalized-ICP, Open3D's ICP (where libopen3d-dev is installed),
// the paper's segmentation followed by a global method and PCL ICP, and MLS resampling.
#pragma once

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/baselines/params.h"
#include "arref/icp/registration_output.h"

namespace arref {

// ICP through PCL (point-to-point, or point-to-plane with normals on both clouds).
Result<RegistrationOutput> RegisterPclIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                          const Iso3& T_world_base_initial, const IcpParams& params,
                                          bool point_to_plane);

// Generalized ICP through PCL (Segal et al. 2009).
Result<RegistrationOutput> RegisterPclGicp(const PointCloud& model_base, const PointCloud& scene_world,
                                           const Iso3& T_world_base_initial, const IcpParams& params);

// ICP through Open3D, when arref_baselines was built with it (ARREF_WITH_OPEN3D).
Result<RegistrationOutput> RegisterOpen3dIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                             const Iso3& T_world_base_initial, const IcpParams& params,
                                             bool point_to_plane);

// The paper's pipeline for global methods (Sec. IV-B): segment the robot near the seed (if
// enabled), align globally, refine with PCL ICP against the whole scene.
enum class GlobalAligner { kSuper4pcs, kPcl4pcs, kPclK4pcs, kFpfhRansac };
struct GlobalParams {
  SegmentationParams segmentation;
  Super4pcsParams super4pcs;
  Pcl4pcsParams pcl_4pcs;  // pcl-4pcs and pcl-k4pcs
  FpfhRansacParams fpfh_ransac;
  IcpParams icp;           // the refinement
};
Result<RegistrationOutput> RegisterGlobalThenIcp(GlobalAligner aligner, const PointCloud& model_base,
                                                 const PointCloud& scene_world, const Iso3& T_world_seed,
                                                 const GlobalParams& params);

// The paper's proposal for automatic referencing (Sec. VI), with no seed: a box of the model's
// bounding-box size slid over the scene in steps of SlidingBoxParams::step_fraction of its sides,
// boxes holding too few points dropped, one SHOT descriptor (PCL SHOTEstimation) per box over
// its points matched against the model's, then PCL ICP from the best box's centre at
// icp_yaws yaws; the fit with the most scene points within 2 cm is kept.
Result<RegistrationOutput> RegisterSlidingBoxShot(const PointCloud& model_base, const PointCloud& scene_world,
                                                  const SlidingBoxParams& params, const IcpParams& icp);

Result<PointCloud> MlsResample(const PointCloud& cloud, const MlsOptions& options);

}  // namespace arref
