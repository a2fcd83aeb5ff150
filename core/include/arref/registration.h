// Registration methods: find T_world_base that lays the robot model onto the scene.
// Every method is reachable by a plain name (e.g. "pcl-icp") through the registry below.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "arref/fast_icp.h"
#include "arref/geometry.h"
#include "arref/sampling.h"
#include "arref/status.h"
#include "arref/tracking_error.h"

namespace arref {

// The paper's ICP knobs (PCL IterativeClosestPoint). Defaults: its best "small" setting.
struct IcpParams {
  double max_correspondence_m = 0.1;
  int max_iterations = 500;
  double transformation_epsilon = 1e-8;  // PCL: squared change of the transform between iterations
  double euclidean_fitness_epsilon = 1e-8;
};

// arref's own method (arref_icp.cpp): a gravity-aligned 4-DoF search around the seed (yaw
// over the full circle, a few heights, a position grid when needed), point-to-plane ICP on
// the model points a person can see, and an ambiguity margin.
struct ArrefIcpParams {
  int yaw_hypotheses = 12;
  // Seeds sit 0-0.3 m above the base: one start in the middle; 4-DoF ICP finds the rest.
  std::vector<double> height_offsets_m = {-0.15};
  double position_step_m = 0.3;    // the expanded search's grid step around the seed
  int position_steps = 1;          // grid of (2 * steps + 1)^2 positions
  double expand_below_score = 0.35;  // widen the search when the best coarse score is lower
  std::size_t coarse_points = 250;
  // The refinement's 8 and 4 cm levels (arref_icp.cpp). 600 points saved ~7 ms a request but
  // lost 5 of the bench's 192 user-like runs within 10 mm (1,000 points: 3).
  std::size_t approach_points = 2000;
  std::size_t fine_points = 2000;
  // The last polish, on the surface refitted in context, averages the mesh's bends over more
  // points: 5,000 instead of 2,000 lifted the bench's 480 user-like runs from 467 to 475 within
  // 10 mm (users' own paths: 464 to 469) for about 5 ms a request (docs/engine.md).
  std::size_t context_points = 5000;
  // ... and against the scene sampled afresh round the fitted robot, this many samples per
  // voxel face (about 4x the small configuration's 16,000 over the crop): with one sample per
  // facet or fewer the nearest one often lies on a neighbouring facet and tilts the residual's
  // plane. 0: polish on the request's own scene samples. See docs/engine.md.
  double context_target_density = 4.0;
  // The last polish weighs each point by the variance this error leaves along its normal, seen
  // from the refit's eyes (tracking_error.h). position_m 0: equal weights. See docs/engine.md.
  TrackingError tracking_error;
  int refine_top = 2;
  bool final_six_dof = false;      // a last 6-DoF step would absorb tilt of the headset world (robots stand upright)
  // Fit the robot as the headset would mesh it (model_reconstruction.h) rather than its exact
  // surface, when the caller supplies it (RegisterScene with a RobotSide does).
  bool expected_surface = true;
  double expected_voxel_m = 0.0;   // the headset mesh's voxel; 0: the cropped scene's median edge length
  bool select_walk = true;         // also try surfaces of one-sided walks round the robot (arref_icp.cpp)
  bool in_context = true;          // refit with the objects mapped round the robot fused in (arref_icp.cpp)
  // Every ICP of the method: point-to-plane, or point-to-point for comparison (arref-icp-point).
  IcpMetric metric = IcpMetric::kPointToPlane;
};

// Turns fit figures into a status (calibrated on simulated cells, see docs/engine.md). The
// paper's RMS is not used: it is 26-50 mm even at the true pose on headset meshes, because part
// of the robot is never seen (domain notes, lesson 3).
struct ConfidenceThresholds {
  double ok_min_inlier_fraction = 0.25;  // visible model points within inlier_threshold_m of the scene
  double ok_min_margin = 0.08;           // score lead over the best distinct alternative pose
  double failed_below_inlier_fraction = 0.15;
};

// The paper's segmentation before a global method (Puljiz et al. 2019, Sec. IV-B): remove
// large planes (floor, walls, table top) with RANSAC, cluster the rest (Euclidean), keep the
// cluster nearest the seed. A kept part much wider than the robot means the robot touches
// other objects (e.g. a table): reported as an error, not registered.
struct SegmentationParams {
  bool enabled = true;
  double plane_distance_m = 0.02;     // RANSAC plane inlier band
  double min_plane_fraction = 0.08;   // a plane is "large" with at least this share of the points
  int max_planes = 4;
  double cluster_tolerance_m = 0.05;  // Euclidean clustering: neighbour distance
  std::size_t min_cluster_points = 20;
  double seed_radius_m = 0.35;        // keep the cluster nearest the seed's vertical axis, if this close
  double max_extent_ratio = 1.5;      // kept width > ratio x robot width: robot touches something
};

// Super4PCS (Mellado, Aiger, Mitra, SGP 2014). Lengths in metres; 0 means derive from the
// model's size (users mostly fail on these scales).
struct Super4pcsParams {
  double overlap = 0.6;            // expected share of the (segmented) scene that is robot
  double delta_m = 0.0;            // accuracy; 0: 1.5 % of the model diagonal, clamped to [1, 3] cm
  std::size_t sample_count = 500;  // points drawn from each cloud for the search
  int max_bases = 300;             // iterations (bases tried)
  double max_time_s = 5.0;
  double max_tilt_deg = 15.0;      // the headset knows gravity: reject tilted candidates (180: off)
  double terminate_lcp = 0.85;     // stop when this share of the scene sample is matched
  std::uint64_t rng_seed = 1;
};

// PCL's 4PCS (FPCSInitialAlignment) and Keypoint-4PCS (KFPCSInitialAlignment).
struct Pcl4pcsParams {
  double overlap = 0.6;
  double delta_m = 0.02;
  int sample_count = 500;
  double voxel_m = 0.03;  // both clouds are voxel-downsampled first (K-4PCS: these are its keypoints)
  int max_time_s = 5;
};

// FPFH features (Rusu et al. 2009) + RANSAC with prerejection (Buch et al. 2013), through PCL.
struct FpfhRansacParams {
  double voxel_m = 0.025;
  double normal_radius_m = 0.06;
  double feature_radius_m = 0.12;
  int max_iterations = 20000;
  int correspondence_randomness = 5;
  double similarity_threshold = 0.85;  // edge-length ratio of the prerejection
  double max_correspondence_m = 0.04;
  double inlier_fraction = 0.2;
};

// One registry entry per value; the registry (methods.cpp) says which are available.
enum class Method {
  kPclIcp, kPclIcpPlane, kPclGicp, kSuper4pcs, kPcl4pcs, kPclK4pcs, kFpfhRansac, kArrefIcp, kArrefIcpFast, kArrefIcpExact,
  kArrefIcpPoint,
  kOpen3dIcp, kOpen3dIcpPlane,  // only when built with Open3D
};

// Everything a request may tune. Method-specific parameter structs live here too.
struct RegistrationOptions {
  double crop_radius_m = 2.0;         // the paper's 2 m sphere around the seed
  std::size_t scene_samples = 16000;  // the paper's "small"; "big" is 256,000
  std::size_t model_samples = 10000;
  std::optional<MlsOptions> mls;      // the paper's "MLS method" (off by default, as its best)
  double voxel_leaf_m = 0.0;          // optional voxel downsampling of the scene sample
  Method method = Method::kArrefIcp;
  IcpParams icp;
  SegmentationParams segmentation;  // global methods only
  Super4pcsParams super4pcs;
  Pcl4pcsParams pcl_4pcs;           // pcl-4pcs and pcl-k4pcs
  FpfhRansacParams fpfh_ransac;
  ArrefIcpParams arref_icp;
  ConfidenceThresholds confidence;
  double inlier_threshold_m = 0.02;
  std::uint64_t sample_seed = 1;      // sampling is deterministic for a seed
  // Where the headset was while it mapped the robot (world frame, e.g. one position per
  // second of the mapping), when the app sends it: arref-icp then models the mesh from those
  // eyes instead of guessing which side of the robot was walked. Empty: unknown.
  std::vector<Vec3> head_path_world;
};

struct RegistrationOutput {
  Iso3 T_world_base = Iso3::Identity();
  int iterations = 0;
  bool converged = false;
  std::vector<std::string> stages;  // which steps ran, e.g. {"pcl-icp"}
  // Methods that rank several candidate poses report the winner's score and its lead over
  // the best distinct runner-up (both as inlier fractions); negative when not applicable.
  double score = -1.0;
  double margin = -1.0;
  int hypotheses = 0;
  std::vector<std::pair<std::string, double>> step_ms;  // the method's own steps, in order (profiling)
};

// What a method gets: model points in the robot base frame, scene points in world, the seed.
class RobotSide;    // pipeline.h

struct MethodInput {
  const PointCloud& model_base;
  const PointCloud& scene_world;
  const Iso3& T_world_seed;
  const RegistrationOptions& options;
  const TargetCloud* scene_target = nullptr;  // scene_world's k-d tree when the caller built one
  // The robot as the headset would mesh it, in the base frame (model_reconstruction.h), if known,
  // walked all round; `robot` makes it for one-sided walks at this voxel size.
  const PointCloud* model_expected = nullptr;
  const RobotSide* robot = nullptr;
  double voxel_m = 0.0;
  const TriangleMesh* scene_mesh_world = nullptr;  // the cropped headset mesh the scene was sampled from
};
using MethodFn = std::function<Result<RegistrationOutput>(const MethodInput&)>;

struct MethodInfo {
  Method method;
  const char* name;
  const char* description;
  MethodFn run;
  bool visible_model_only = false;  // fits (and so is measured on) the visible model points only
  bool uses_expected_surface = false;  // fits MethodInput::model_expected when given
  // ConfidenceThresholds were calibrated on this method's fits (docs/engine.md); no other
  // method's result is ever OK.
  bool status_calibrated = false;
};
const std::vector<MethodInfo>& Methods();
const MethodInfo& MethodInfoOf(Method method);

Result<Method> ParseMethod(const std::string& name);
const char* MethodName(Method method);
std::vector<std::string> MethodNames();

Result<RegistrationOutput> RegisterArrefIcp(const MethodInput& input);

// Generalized ICP through PCL (Segal et al. 2009), for comparison.
Result<RegistrationOutput> RegisterPclGicp(const PointCloud& model_base, const PointCloud& scene_world,
                                           const Iso3& T_world_base_initial, const IcpParams& params);

// ICP through Open3D, when arref was built with it (ARREF_WITH_OPEN3D).
Result<RegistrationOutput> RegisterOpen3dIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                             const Iso3& T_world_base_initial, const IcpParams& params,
                                             bool point_to_plane);

// ICP through PCL (point-to-point, or point-to-plane with normals on both clouds).
Result<RegistrationOutput> RegisterPclIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                          const Iso3& T_world_base_initial, const IcpParams& params,
                                          bool point_to_plane);

}  // namespace arref
