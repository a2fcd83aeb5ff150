// The registry of registration methods: one line per method.
#include <stdexcept>

#include "arref/registration.h"
#include "global_registration.h"

namespace arref {
namespace {

// arref-icp with its parameters changed by `change`: a variant of the default method.
template <typename Change>
Result<RegistrationOutput> WithArrefIcpParams(const MethodInput& in, Change change) {
  RegistrationOptions options = in.options;
  change(options.arref_icp);
  return RegisterArrefIcp(MethodInput{in.model_base, in.scene_world, in.T_world_seed, options, in.scene_target,
                                      in.model_expected, in.robot, in.voxel_m, in.scene_mesh_world});
}

}  // namespace

const std::vector<MethodInfo>& Methods() {
  static const std::vector<MethodInfo> kMethods = {
      {Method::kArrefIcp, "arref-icp",
       "arref's default: 4-DoF yaw/height/position search around the seed, point-to-plane ICP of the robot as the "
       "headset would mesh it",
       RegisterArrefIcp, true, true, true},
      {Method::kArrefIcpFast, "arref-icp-fast",
       "arref-icp without its per-request refit among the objects mapped round the robot: faster, and a table near the "
       "robot pulls it a few mm",
       [](const MethodInput& in) {
         return WithArrefIcpParams(in, [](ArrefIcpParams& p) { p.in_context = false; });
       },
       true, true, true},
      {Method::kArrefIcpExact, "arref-icp-exact",
       "arref-icp fitting the robot's exact surface (its visible parts), for comparison", RegisterArrefIcp, true, false,
       true},
      {Method::kArrefIcpPoint, "arref-icp-point",
       "arref-icp with point-to-point instead of point-to-plane residuals in every ICP, for comparison (never OK: "
       "the status was calibrated on point-to-plane fits, and one of its fits 21 mm off passed it)",
       [](const MethodInput& in) {
         return WithArrefIcpParams(in, [](ArrefIcpParams& p) { p.metric = IcpMetric::kPointToPoint; });
       },
       true, true},
      {Method::kPclIcp, "pcl-icp", "PCL point-to-point ICP from the seed (the paper's method)",
       [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, false);
       }},
      {Method::kPclIcpPlane, "pcl-icp-plane", "PCL point-to-plane ICP from the seed",
       [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, true);
       }},
      {Method::kPclGicp, "pcl-gicp", "PCL Generalized-ICP from the seed (for comparison)",
       [](const MethodInput& in) {
         return RegisterPclGicp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp);
       }},
#ifdef ARREF_WITH_OPEN3D
      {Method::kOpen3dIcp, "open3d-icp", "Open3D point-to-point ICP from the seed (for comparison)",
       [](const MethodInput& in) {
         return RegisterOpen3dIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, false);
       }},
      {Method::kOpen3dIcpPlane, "open3d-icp-plane", "Open3D point-to-plane ICP from the seed (for comparison)",
       [](const MethodInput& in) {
         return RegisterOpen3dIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, true);
       }},
#endif
      {Method::kSuper4pcs, "super4pcs", "the paper's segmentation, Super4PCS (Mellado et al. 2014), then PCL ICP",
       [](const MethodInput& in) {
         return RunGlobalThenIcp(in, "super4pcs", [&](const PointCloud& model, const PointCloud& scene) {
           return AlignSuper4pcs(model, scene, in.options.super4pcs);
         });
       }},
      {Method::kPcl4pcs, "pcl-4pcs", "segmentation, PCL 4PCS (FPCSInitialAlignment), then PCL ICP",
       [](const MethodInput& in) {
         return RunGlobalThenIcp(in, "pcl-4pcs", [&](const PointCloud& model, const PointCloud& scene) {
           return AlignPcl4pcs(model, scene, in.options.pcl_4pcs, false);
         });
       }},
      {Method::kPclK4pcs, "pcl-k4pcs", "segmentation, PCL Keypoint-4PCS (KFPCSInitialAlignment), then PCL ICP",
       [](const MethodInput& in) {
         return RunGlobalThenIcp(in, "pcl-k4pcs", [&](const PointCloud& model, const PointCloud& scene) {
           return AlignPcl4pcs(model, scene, in.options.pcl_4pcs, true);
         });
       }},
      {Method::kFpfhRansac, "fpfh-ransac", "segmentation, FPFH features + RANSAC with prerejection (PCL), then PCL ICP",
       [](const MethodInput& in) {
         return RunGlobalThenIcp(in, "fpfh-ransac", [&](const PointCloud& model, const PointCloud& scene) {
           return AlignFpfhRansac(model, scene, in.options.fpfh_ransac);
         });
       }},
  };
  return kMethods;
}

const MethodInfo& MethodInfoOf(Method method) {
  for (const auto& m : Methods())
    if (m.method == method) return m;
  throw std::logic_error("registration method missing from the registry");  // a programming error
}

Result<Method> ParseMethod(const std::string& name) {
  for (const auto& m : Methods())
    if (name == m.name) return m.method;
  std::string known;
  for (const auto& n : MethodNames()) known += (known.empty() ? "" : ", ") + n;
  return Status::InvalidArgument("unknown registration method '" + name + "' (available: " + known + ")");
}

const char* MethodName(Method method) { return MethodInfoOf(method).name; }

std::vector<std::string> MethodNames() {
  std::vector<std::string> names;
  for (const auto& m : Methods()) names.emplace_back(m.name);
  return names;
}

}  // namespace arref
