// The registry of registration methods and the options of a request. Every method is
// reachable by a plain name (e.g. "pcl-icp"); the table (methods.cpp) lists those built in.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/baselines/params.h"
#include "arref/icp/arref_icp.h"
#include "arref/icp/fast_icp.h"
#include "arref/icp/registration_output.h"

namespace arref {

class RobotSide;  // fusion/robot_side.h

// Turns fit figures into a status (calibrated on simulated cells, see docs/engine.md). The
// paper's RMS is not used: it is 26-50 mm even at the true pose on headset meshes, because part
// of the robot is never seen.
struct ConfidenceThresholds {
  double ok_min_inlier_fraction = 0.25;  // visible model points within inlier_threshold_m of the scene
  double ok_min_margin = 0.08;           // score lead over the best distinct alternative pose
  // ... and over the fit turned about the base by 100 mm of ADD: an arm that is nearly a figure
  // of revolution slides along its yaw valley, and every refined candidate ends at one pose.
  // Good fits of the dev robots lead by 0.047 or more, wrong ones of a slender proxy arm by
  // 0.02 or less (docs/robustness.md, "The fit turned about its base").
  double ok_min_turned_lead = 0.03;
  double failed_below_inlier_fraction = 0.15;
  // A headset mesh with fewer voxels than this across the robot's largest side is not OK: its fused
  // shell leaves a small arm's pose uncertain by more than a centimetre (docs/robustness.md).
  double min_voxels_across_robot = 20.0;
  // A fit whose own expected error (FitPrecision::expected_error_m, one standard deviation as an
  // RMS over the robot's points) is over this is not OK: the product promises holograms within a
  // centimetre, and two such deviations reach the 2 cm at which the bench calls a pose wrong.
  // 0 turns the check off.
  double ok_max_expected_error_m = 0.010;
};

// The seedless method's detection (arref-auto, pipeline/seedless.h).
struct SeedlessParams {
  // Candidate bases refined with arref-icp (the best distinct ones of the detection).
  std::size_t max_candidates = 8;
  // The detection's occupancy cell, as a fraction of the robot's largest bounding-box side
  // (never finer than the mesh's voxel).
  double cell_fraction = 1.0 / 12.0;
  int yaws = 12;
  // Map samples per detection cell face (the occupancy grid is filled from them).
  double samples_per_cell_face = 6.0;
  std::size_t max_map_samples = 600000;
};

// One registry entry per value; the registry (methods.cpp) says which are built in.
enum class Method {
  kPclIcp, kPclIcpPlane, kPclGicp, kSuper4pcs, kPcl4pcs, kPclK4pcs, kFpfhRansac, kArrefIcp, kArrefIcpFast, kArrefIcpExact,
  kArrefIcpPoint,
  kOpen3dIcp, kOpen3dIcpPlane,
  kArrefAuto, kSlidingBoxShot,  // seedless: the whole map (pipeline/seedless.h)
};

// Everything a request may tune: the pipeline's stages, then each method family's parameters.
struct RegistrationOptions {
  double crop_radius_m = 2.0;         // the paper's 2 m sphere around the seed
  std::size_t scene_samples = 16000;  // the paper's "small"; "big" is 256,000
  std::size_t model_samples = 10000;
  std::optional<MlsOptions> mls;      // the paper's "MLS method" (off by default, as its best)
  double voxel_leaf_m = 0.0;          // optional voxel downsampling of the scene sample
  Method method = Method::kArrefIcp;
  IcpParams icp;                    // pcl-icp and friends, and the global methods' refinement
  SegmentationParams segmentation;  // global methods only
  Super4pcsParams super4pcs;
  Pcl4pcsParams pcl_4pcs;           // pcl-4pcs and pcl-k4pcs
  FpfhRansacParams fpfh_ransac;
  ArrefIcpParams arref_icp;
  SeedlessParams seedless;          // arref-auto
  SlidingBoxParams sliding_box;     // sliding-box-shot
  ConfidenceThresholds confidence;
  double inlier_threshold_m = 0.02;
  std::uint64_t sample_seed = 1;      // sampling is deterministic for a seed
  // Where the headset was while it mapped the robot (world frame, e.g. one position per
  // second of the mapping), when the app sends it: arref-icp then models the mesh from those
  // eyes instead of guessing which side of the robot was walked. Empty: unknown.
  std::vector<Vec3> head_path_world;
  // Non-empty: why the map does not show the robot as posed (its joints moved while the map was
  // made: ChooseMovingFit's much_moved). The status is then at most LOW_CONFIDENCE, with this as
  // its reason, whatever the fit rests on.
  std::string map_not_as_posed;
};

// What a method gets from the pipeline: model points in the robot base frame, scene points in
// world with their k-d tree, the seed, and the request's options.
struct MethodInput {
  const PointCloud& model_base;
  const PointCloud& scene_world;
  const TargetCloud& scene_target;
  const Iso3& T_world_seed;
  const RegistrationOptions& options;
  // Optional: the robot's model side, its surface as the headset would mesh it at voxel_m
  // (null: not known), and the cropped headset mesh the scene was sampled from.
  const RobotSide* robot = nullptr;
  std::shared_ptr<const PointCloud> model_expected;
  double voxel_m = 0.0;
  const TriangleMesh* scene_mesh_world = nullptr;
  const CancelToken* cancel = nullptr;
};
using MethodFn = std::function<Result<RegistrationOutput>(const MethodInput&)>;

struct MethodInfo {
  Method method;
  const char* name;
  const char* description;
  MethodFn run;
  bool visible_model_only = false;     // fits (and so is measured on) the visible model points only
  bool uses_expected_surface = false;  // fits MethodInput::model_expected when given
  // ConfidenceThresholds were calibrated on this method's fits (docs/engine.md); no other
  // method's result is ever OK.
  bool status_calibrated = false;
  // Searches the whole map and takes no seed (RegisterWholeMap); `run` then refuses a seeded request.
  bool seedless = false;
};
const std::vector<MethodInfo>& Methods();
// The entry of a method, or null when it is not built in (the baselines need ARREF_WITH_PCL).
const MethodInfo* FindMethod(Method method);

Result<Method> ParseMethod(const std::string& name);
const char* MethodName(Method method);
std::vector<std::string> MethodNames();

}  // namespace arref
