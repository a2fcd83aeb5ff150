// From a RegisterRequest to a Job: validation of every field and the fallbacks to what the
// session already holds (seed, joint states). Pure functions of their inputs, so each field's
// error can be tested without a socket; the session only adds its scene and callbacks.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>

#include "arref/base/frames.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/pipeline/pipeline.h"
#include "arref/pipeline/seedless.h"
#include "job_scheduler.h"
#include "robot_registry.h"
#include "wire.h"

namespace arref::server {

// RegisterRequest.head_path holds at most this many positions (arref.proto).
constexpr std::size_t kMaxHeadPathPositions = 10000;

// The allowed range of each RegistrationParams override (inclusive), checked here and
// announced in HelloReply.limits.params.
struct ParamRange {
  const char* name;
  double min;
  double max;
};
inline constexpr ParamRange kCropRadiusRange{"crop_radius_m", 0.01, 50.0};
inline constexpr ParamRange kSceneSamplesRange{"scene_samples", 3, 2'000'000};
inline constexpr ParamRange kIcpMaxCorrespondenceRange{"icp_max_correspondence_m", 1e-4, 10.0};
inline constexpr ParamRange kIcpMaxIterationsRange{"icp_max_iterations", 1, 100'000};
inline constexpr ParamRange kParamRanges[] = {kCropRadiusRange, kSceneSamplesRange, kIcpMaxCorrespondenceRange,
                                              kIcpMaxIterationsRange};

// The session's latest JointState for one robot id: its values, or why it was rejected (a
// rejected state is kept so that requests which would use it fail instead of running on
// defaults; arref.proto, JointState).
struct SessionJoints {
  JointValues values;
  std::string rejected;  // non-empty: the rejection's message
};

// What a session knows when a request arrives, used where the request leaves a field unset.
struct SessionDefaults {
  std::optional<Iso3> seed;                                  // last SeedPose
  FrameConvention seed_frame = FrameConvention::kUnity;      // its frame: results default to it
  const std::map<std::string, SessionJoints>* joints = nullptr;  // JointState by robot id ("": any)
};

// The configured options overridden by the request's method, head path and params, each
// range-checked; an error names the field ("RegisterRequest.method: ...", "params.x = ...").
Result<RegistrationOptions> RequestOptions(const wire::pb::RegisterRequest& m, const RegistrationOptions& configured);

// The complete joint state of the request: its own joints, else the session's state for the
// robot, else the session's state for any robot, over the robot's defaults. A session state
// that was rejected fails the request (kInvalidArgument naming it).
Result<JointValues> RequestJoints(const wire::pb::RegisterRequest& m, const ServedRobot& robot,
                                  const RobotRegistry& robots, const SessionDefaults& session);

// The request's optional hints (gaze point, wearer position) in world, ROS convention.
Result<InstanceHint> RequestHint(const wire::pb::RegisterRequest& m);

// A job for the request with everything but the scene, the session id and the callbacks,
// which the session adds. Errors and the wire code they become (RequestErrorCode):
//   kNotFound           unknown robot        -> UNKNOWN_ROBOT
//   kFailedPrecondition no seed at all for a method that needs one -> NO_SEED
// With no seed anywhere and no method named (or a seedless one), the job searches the whole map
// (Job::seedless, method arref-auto by default).
//   kInvalidArgument    any bad field        -> INVALID_ARGUMENT
// Checked in that order (seed before joints before options), as the protocol documents.
Result<std::shared_ptr<Job>> BuildJob(const wire::pb::RegisterRequest& m, const RobotRegistry& robots,
                                      const RegistrationOptions& configured, const SessionDefaults& session);

wire::pb::ErrorCode RequestErrorCode(const Status& status);

// What a JointState does to the session, for the live session and for replay alike: `keep`
// (store `joints` under the message's robot id, rejected or not) and, when `error` is set, the
// Error to answer with. An unknown robot is answered and nothing is kept.
struct JointStateOutcome {
  bool keep = true;
  SessionJoints joints;
  // The robot's complete joints (its defaults under the message's values), when the message
  // names a served robot and was accepted: what its joint stream takes (FeedJointStream).
  JointValues complete;
  wire::pb::ErrorCode error = wire::pb::ERROR_CODE_UNSPECIFIED;
  std::string message;
};
JointStateOutcome ReadJointState(const wire::pb::JointState& m, const RobotRegistry& robots);

}  // namespace arref::server
