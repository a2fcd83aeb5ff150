// Registration methods: find T_world_base that lays the robot model onto the scene.
#pragma once

#include <string>
#include <vector>

#include "arref/geometry.h"
#include "arref/status.h"

namespace arref {

// The paper's ICP knobs (PCL IterativeClosestPoint). Defaults: its best "small" setting.
struct IcpParams {
  double max_correspondence_m = 0.1;
  int max_iterations = 500;
  double transformation_epsilon = 1e-8;  // PCL: squared change of the transform between iterations
  double euclidean_fitness_epsilon = 1e-8;
};

struct RegistrationOutput {
  Iso3 T_world_base = Iso3::Identity();
  int iterations = 0;
  bool converged = false;
  std::vector<std::string> stages;  // which steps ran, e.g. {"pcl-icp"}
};

enum class Method { kPclIcp, kPclIcpPlane };
Result<Method> ParseMethod(const std::string& name);
const char* MethodName(Method method);
std::vector<std::string> MethodNames();

// model_base: robot surface points in its base frame; scene_world: headset points in world.
// Point-to-plane needs normals on both clouds.
Result<RegistrationOutput> RegisterPclIcp(const PointCloud& model_base, const PointCloud& scene_world,
                                          const Iso3& T_world_base_initial, const IcpParams& params,
                                          bool point_to_plane);

}  // namespace arref
