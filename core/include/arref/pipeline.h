// The referencing pipeline of one request (Puljiz et al. 2019, Fig. 2): crop the headset mesh
// around the seed, sample it, optionally resample (MLS), register the robot model, measure.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "arref/geometry.h"
#include "arref/registration.h"
#include "arref/robot_model.h"
#include "arref/sampling.h"
#include "arref/status.h"

namespace arref {

struct StageTime {
  std::string stage;
  double ms = 0.0;
};

struct RegistrationReport {
  Iso3 T_world_base = Iso3::Identity();
  Iso3 T_world_seed = Iso3::Identity();
  std::string method;
  std::vector<std::string> stages_run;
  double rms_m = 0.0;
  double inlier_fraction = 0.0;
  int iterations = 0;
  bool converged = false;
  std::size_t scene_triangles = 0;  // after cropping
  std::size_t scene_points = 0;     // registered against
  std::size_t model_points = 0;
  std::vector<StageTime> timings;
  double total_ms() const;
};

// Called with a stage name and overall fraction done in [0, 1].
using ProgressFn = std::function<void(std::string_view stage, double fraction)>;

// Robot surface points in its base frame, posed by joints (model side, reusable across requests).
Result<PointCloud> SampleRobot(const RobotModel& robot, const JointValues& joints, std::size_t samples,
                               std::uint64_t seed);

Result<RegistrationReport> RegisterScene(const PointCloud& model_base, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress = {});

}  // namespace arref
