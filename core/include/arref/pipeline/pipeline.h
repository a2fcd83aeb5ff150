// The referencing pipeline of one request (Puljiz et al. 2019, Fig. 2): crop the headset mesh
// around the seed, sample it, optionally resample (MLS), register the robot model, measure.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/cancel.h"
#include "arref/fusion/robot_side.h"
#include "arref/icp/fit_precision.h"
#include "arref/icp/registration_output.h"
#include "arref/pipeline/registration.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/sampling.h"
#include "arref/base/status.h"

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
  // LOW_CONFIDENCE only because its expected error is over ConfidenceThresholds::ok_max_expected_error_m:
  // every check of where the robot stands passed, but not of how precisely.
  bool imprecise_only = false;
  Iso3 T_world_base = Iso3::Identity();
  Iso3 T_world_seed = Iso3::Identity();
  std::string method;
  std::vector<std::string> stages_run;
  double rms_m = 0.0;                // the paper's metric over the points named by rms_points
  std::string rms_points = "all";   // "all" model points, or "visible" ones (those the method fits)
  double inlier_fraction = 0.0;     // visible model points within inlier_threshold_m of the scene
  double score = -1.0;              // method's own ranking score and ambiguity margin (-1: none)
  double margin = -1.0;
  std::optional<TurnedFit> turned;  // the fit against itself turned about its base (the method's)
  int hypotheses = 0;
  // How far the pose may be off (fit_precision.h): the fit's residuals, the headset map's
  // tracking error and the surface models' disagreement. Not whether it is in the right place.
  FitPrecision precision;
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

// One request: crop, sample, optionally resample, register, measure. With a RobotSide,
// methods that can fit the robot as the headset would mesh it (arref-icp) do so.
Result<RegistrationReport> RegisterScene(const RobotSide& robot, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress = {}, const CancelToken* cancel = nullptr);
// The same with the exact model surface only.
Result<RegistrationReport> RegisterScene(const PointCloud& model_base, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress = {}, const CancelToken* cancel = nullptr);

}  // namespace arref
