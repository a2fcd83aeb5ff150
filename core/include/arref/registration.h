// Registration methods: find T_world_base that lays the robot model onto the scene.
// Every method is reachable by a plain name (e.g. "pcl-icp") through the registry below.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "arref/geometry.h"
#include "arref/sampling.h"
#include "arref/status.h"

namespace arref {

// The paper's ICP knobs (PCL IterativeClosestPoint). Defaults: its best "small" setting.
struct IcpParams {
  double max_correspondence_m = 0.1;
  int max_iterations = 500;
  double transformation_epsilon = 1e-8;  // PCL: squared change of the transform between iterations
  double euclidean_fitness_epsilon = 1e-8;
};

// One registry entry per value; the registry (methods.cpp) says which are available.
enum class Method { kPclIcp, kPclIcpPlane };

// Everything a request may tune. Method-specific parameter structs live here too.
struct RegistrationOptions {
  double crop_radius_m = 2.0;         // the paper's 2 m sphere around the seed
  std::size_t scene_samples = 16000;  // the paper's "small"; "big" is 256,000
  std::size_t model_samples = 10000;
  std::optional<MlsOptions> mls;      // the paper's "MLS method" (off by default, as its best)
  double voxel_leaf_m = 0.0;          // optional voxel downsampling of the scene sample
  Method method = Method::kPclIcp;
  IcpParams icp;
  double inlier_threshold_m = 0.02;
  std::uint64_t sample_seed = 1;      // sampling is deterministic for a seed
};

struct RegistrationOutput {
  Iso3 T_world_base = Iso3::Identity();
  int iterations = 0;
  bool converged = false;
  std::vector<std::string> stages;  // which steps ran, e.g. {"pcl-icp"}
};

// What a method gets: model points in the robot base frame, scene points in world, the seed.
struct MethodInput {
  const PointCloud& model_base;
  const PointCloud& scene_world;
  const Iso3& T_world_seed;
  const RegistrationOptions& options;
};
using MethodFn = std::function<Result<RegistrationOutput>(const MethodInput&)>;

struct MethodInfo {
  Method method;
  const char* name;
  const char* description;
  MethodFn run;
};
const std::vector<MethodInfo>& Methods();
const MethodInfo& MethodInfoOf(Method method);

Result<Method> ParseMethod(const std::string& name);
const char* MethodName(Method method);
std::vector<std::string> MethodNames();

// ICP through PCL (point-to-point, or point-to-plane with normals on both clouds).
Result<RegistrationOutput> RegisterPclIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                          const Iso3& T_world_base_initial, const IcpParams& params,
                                          bool point_to_plane);

}  // namespace arref
