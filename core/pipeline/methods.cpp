// The registry of registration methods: one entry per method, with named fields.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include "arref/fusion/robot_side.h"
#include "arref/pipeline/registration.h"
#ifdef ARREF_WITH_PCL
#include "arref/baselines/baselines.h"
#endif

namespace arref {
namespace {

// arref-icp with its parameters changed by `change`: the default method and its variants.
template <typename Change>
Result<RegistrationOutput> ArrefIcpWith(const MethodInput& in, Change change) {
  ArrefIcpParams params = in.options.arref_icp;
  change(params);
  return RegisterArrefIcp(ArrefIcpInput{.model_base = in.model_base,
                                        .scene_world = in.scene_world,
                                        .scene_target = in.scene_target,
                                        .T_world_seed = in.T_world_seed,
                                        .params = params,
                                        .robot = in.robot,
                                        .model_expected = in.model_expected,
                                        .voxel_m = in.voxel_m,
                                        .scene_mesh_world = in.scene_mesh_world,
                                        .head_path_world = in.options.head_path_world,
                                        .sample_seed = in.options.sample_seed,
                                        .cancel = in.cancel});
}

Result<RegistrationOutput> ArrefIcp(const MethodInput& in) {
  return ArrefIcpWith(in, [](ArrefIcpParams&) {});
}

std::vector<MethodInfo> ProductMethods() {
  return {
      {.method = Method::kArrefIcp,
       .name = "arref-icp",
       .description = "arref's default: 4-DoF yaw/height/position search around the seed, point-to-plane ICP of the "
                      "robot as the headset would mesh it",
       .run = ArrefIcp,
       .visible_model_only = true,
       .uses_expected_surface = true,
       .status_calibrated = true},
      {.method = Method::kArrefIcpFast,
       .name = "arref-icp-fast",
       .description = "arref-icp without its per-request refit among the objects mapped round the robot: faster, and "
                      "a table near the robot pulls it a few mm",
       .run = [](const MethodInput& in) { return ArrefIcpWith(in, [](ArrefIcpParams& p) { p.in_context = false; }); },
       .visible_model_only = true,
       .uses_expected_surface = true,
       .status_calibrated = true},
      {.method = Method::kArrefIcpExact,
       .name = "arref-icp-exact",
       .description = "arref-icp fitting the robot's exact surface (its visible parts), for comparison",
       .run = ArrefIcp,
       .visible_model_only = true,
       .status_calibrated = true},
      {.method = Method::kArrefIcpPoint,
       .name = "arref-icp-point",
       .description = "arref-icp with point-to-point instead of point-to-plane residuals in every ICP, for comparison "
                      "(never OK: the status was calibrated on point-to-plane fits, and one of its fits 21 mm off "
                      "passed it)",
       .run = [](const MethodInput& in) {
         return ArrefIcpWith(in, [](ArrefIcpParams& p) { p.metric = IcpMetric::kPointToPoint; });
       },
       .visible_model_only = true,
       .uses_expected_surface = true},
      {.method = Method::kArrefAuto,
       .name = "arref-auto",
       .description = "arref's default with no seed: candidate bases from the whole map's supports and occupancy, "
                      "arref-icp from each, every distinct instance ranked (RegisterWholeMap)",
       .run = [](const MethodInput&) -> Result<RegistrationOutput> {
         return Status::InvalidArgument("arref-auto searches the whole map and takes no seed: send the request without one");
       },
       .visible_model_only = true,
       .uses_expected_surface = true,
       .status_calibrated = true,
       .seedless = true},
  };
}

#ifdef ARREF_WITH_PCL
GlobalParams GlobalParamsOf(const RegistrationOptions& o) {
  return {.segmentation = o.segmentation,
          .super4pcs = o.super4pcs,
          .pcl_4pcs = o.pcl_4pcs,
          .fpfh_ransac = o.fpfh_ransac,
          .icp = o.icp};
}

MethodFn GlobalMethod(GlobalAligner aligner) {
  return [aligner](const MethodInput& in) {
    return RegisterGlobalThenIcp(aligner, in.model_base, in.scene_world, in.T_world_seed, GlobalParamsOf(in.options));
  };
}

std::vector<MethodInfo> BaselineMethods() {
  std::vector<MethodInfo> out = {
      {.method = Method::kPclIcp,
       .name = "pcl-icp",
       .description = "PCL point-to-point ICP from the seed (the paper's method)",
       .run = [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, false);
       }},
      {.method = Method::kPclIcpPlane,
       .name = "pcl-icp-plane",
       .description = "PCL point-to-plane ICP from the seed",
       .run = [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, true);
       }},
      {.method = Method::kPclGicp,
       .name = "pcl-gicp",
       .description = "PCL Generalized-ICP from the seed (for comparison)",
       .run = [](const MethodInput& in) {
         return RegisterPclGicp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp);
       }},
#ifdef ARREF_WITH_OPEN3D
      {.method = Method::kOpen3dIcp,
       .name = "open3d-icp",
       .description = "Open3D point-to-point ICP from the seed (for comparison)",
       .run = [](const MethodInput& in) {
         return RegisterOpen3dIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, false);
       }},
      {.method = Method::kOpen3dIcpPlane,
       .name = "open3d-icp-plane",
       .description = "Open3D point-to-plane ICP from the seed (for comparison)",
       .run = [](const MethodInput& in) {
         return RegisterOpen3dIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, true);
       }},
#endif
      {.method = Method::kSuper4pcs,
       .name = "super4pcs",
       .description = "the paper's segmentation, Super4PCS (Mellado et al. 2014), then PCL ICP",
       .run = GlobalMethod(GlobalAligner::kSuper4pcs)},
      {.method = Method::kPcl4pcs,
       .name = "pcl-4pcs",
       .description = "segmentation, PCL 4PCS (FPCSInitialAlignment), then PCL ICP",
       .run = GlobalMethod(GlobalAligner::kPcl4pcs)},
      {.method = Method::kPclK4pcs,
       .name = "pcl-k4pcs",
       .description = "segmentation, PCL Keypoint-4PCS (KFPCSInitialAlignment), then PCL ICP",
       .run = GlobalMethod(GlobalAligner::kPclK4pcs)},
      {.method = Method::kFpfhRansac,
       .name = "fpfh-ransac",
       .description = "segmentation, FPFH features + RANSAC with prerejection (PCL), then PCL ICP",
       .run = GlobalMethod(GlobalAligner::kFpfhRansac)},
      {.method = Method::kSlidingBoxShot,
       .name = "sliding-box-shot",
       .description = "the paper's proposal with no seed: a robot-sized box slid over the map, SHOT descriptors "
                      "matched against the model's, PCL ICP from the best box at four yaws",
       .run = [](const MethodInput& in) {
         return RegisterSlidingBoxShot(in.model_base, in.scene_world, in.options.sliding_box, in.options.icp);
       },
       .seedless = true},
  };
  return out;
}
#endif

std::vector<MethodInfo> AllMethods() {
  std::vector<MethodInfo> all = ProductMethods();
#ifdef ARREF_WITH_PCL
  for (auto& m : BaselineMethods()) all.push_back(std::move(m));
#endif
  return all;
}

}  // namespace

const std::vector<MethodInfo>& Methods() {
  static const std::vector<MethodInfo> kMethods = AllMethods();
  return kMethods;
}

const MethodInfo* FindMethod(Method method) {
  for (const auto& m : Methods())
    if (m.method == method) return &m;
  return nullptr;
}

Result<Method> ParseMethod(const std::string& name) {
  for (const auto& m : Methods())
    if (name == m.name) return m.method;
  return Status::InvalidArgument(
      fmt::format("unknown registration method '{}' (available: {})", name, fmt::join(MethodNames(), ", ")));
}

const char* MethodName(Method method) {
  const MethodInfo* info = FindMethod(method);
  return info ? info->name : "unavailable-method";
}

std::vector<std::string> MethodNames() {
  std::vector<std::string> names;
  for (const auto& m : Methods()) names.emplace_back(m.name);
  return names;
}

}  // namespace arref
