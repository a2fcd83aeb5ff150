// The referencing pipeline of one request (Puljiz et al. 2019, Fig. 2): crop the headset mesh
// around the seed, sample it, optionally resample (MLS), register the robot model, measure.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "arref/geometry.h"
#include "arref/model_reconstruction.h"
#include "arref/registration.h"
#include "arref/robot_model.h"
#include "arref/sampling.h"
#include "arref/status.h"

namespace arref {

struct StageTime {
  std::string stage;
  double ms = 0.0;
};

// How far a result can be trusted (ConfidenceThresholds in registration.h).
enum class ResultStatus { kOk, kLowConfidence, kFailed };
const char* ResultStatusName(ResultStatus status);  // "OK", "LOW_CONFIDENCE", "FAILED"

struct RegistrationReport {
  ResultStatus status = ResultStatus::kOk;
  std::string status_reason;        // why it is not OK
  Iso3 T_world_base = Iso3::Identity();
  Iso3 T_world_seed = Iso3::Identity();
  std::string method;
  std::vector<std::string> stages_run;
  double rms_m = 0.0;                // the paper's metric over the points named by rms_points
  std::string rms_points = "all";   // "all" model points, or "visible" ones (those the method fits)
  double inlier_fraction = 0.0;     // visible model points within inlier_threshold_m of the scene
  double score = -1.0;              // method's own ranking score and ambiguity margin (-1: none)
  double margin = -1.0;
  int hypotheses = 0;
  int iterations = 0;
  bool converged = false;
  std::size_t scene_triangles = 0;  // after cropping
  std::size_t scene_points = 0;     // registered against
  std::size_t model_points = 0;
  std::vector<StageTime> timings;
  std::vector<StageTime> method_steps;  // inside the "register" stage, for methods that time theirs
  double total_ms() const;
};

// Called with a stage name and overall fraction done in [0, 1].
using ProgressFn = std::function<void(std::string_view stage, double fraction)>;

// Robot surface points with normals in its base frame, posed by joints, with the visibility
// of each point (model_visibility.h). Model side: reusable across requests.
Result<PointCloud> SampleRobot(const RobotModel& robot, const JointValues& joints, std::size_t samples,
                               std::uint64_t seed);
// The same from the robot's already posed mesh (base frame); name is for error messages.
Result<PointCloud> SamplePosedRobot(const TriangleMesh& mesh_base, const std::string& name, std::size_t samples,
                                    std::uint64_t seed);

// The robot side of registrations, built once per robot and joint state and shared by
// requests (the server caches it): the samples of SampleRobot, and the robot as a headset
// would mesh it (model_reconstruction.h), made on first use for each voxel size.
class RobotSide {
 public:
  static Result<std::shared_ptr<const RobotSide>> Create(const RobotModel& robot, const JointValues& joints,
                                                         std::size_t samples, std::uint64_t seed);
  const PointCloud& samples() const { return samples_; }
  // Cached per millimetre of voxel size and walk; thread-safe. walk -1: all round; k in
  // [0, kWalks): a 216 degree arc centred at k * 360 / kWalks degrees. thinned_to > 0: at most
  // that many of its points (Thinned), as a method fits them. The first call for a voxel size
  // makes every walk's surface.
  static constexpr int kWalks = 8;
  Result<std::shared_ptr<const PointCloud>> Expected(double voxel_m, int walk = -1, std::size_t thinned_to = 0) const;
  // The samples a person can see (VisiblePoints), Thinned; cached, thread-safe.
  std::shared_ptr<const PointCloud> Visible(std::size_t thinned_to) const;
  // The same with the objects mapped round the robot, from the headset's mesh with the robot
  // at T_world_base (ExpectedSurfaceMaker::MakeInContext). Made anew on every call.
  // eyes_base: where the headset really was (base frame); empty: the walk's eyes.
  Result<PointCloud> ExpectedInContext(double voxel_m, int walk, const TriangleMesh& scene_world,
                                       const Iso3& T_world_base, const std::vector<Vec3>& eyes_base = {}) const;
  // The eyes ExpectedInContext fuses from when it is given none (base frame).
  static std::vector<Vec3> RefitEyes(int walk);

 private:
  RobotSide(TriangleMesh mesh_base, PointCloud samples, std::uint64_t seed);
  using ExpectedKey = std::tuple<long, int, std::size_t>;  // voxel in mm, walk, thinned_to
  Result<std::shared_ptr<const PointCloud>> ExpectedLocked(const ExpectedKey& key) const;  // under mutex_
  void MakeEveryWalk(long voxel_mm) const;  // into expected_ or failed_, under mutex_
  Result<std::shared_ptr<const ExpectedSurfaceMaker>> Maker() const;  // under mutex_
  TriangleMesh mesh_base_;
  PointCloud samples_;
  std::uint64_t seed_;
  mutable std::mutex mutex_;
  mutable std::shared_ptr<const ExpectedSurfaceMaker> maker_;  // made on first use
  mutable std::map<ExpectedKey, std::shared_ptr<const PointCloud>> expected_;
  mutable std::map<ExpectedKey, Status> failed_;
  mutable std::map<std::size_t, std::shared_ptr<const PointCloud>> visible_;
};

// One request: crop, sample, optionally resample, register, measure. With a RobotSide,
// methods that can fit the robot as the headset would mesh it (arref-icp) do so.
Result<RegistrationReport> RegisterScene(const RobotSide& robot, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress = {});
// The same with the exact model surface only.
Result<RegistrationReport> RegisterScene(const PointCloud& model_base, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress = {});

}  // namespace arref
