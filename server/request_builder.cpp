#include "request_builder.h"

#include <fmt/format.h>

#include "convert.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

// Range check of an optional override; the message names the field and its range.
template <typename T>
Status CheckRange(const ParamRange& range, T value) {
  if (!(value >= static_cast<T>(range.min) && value <= static_cast<T>(range.max)))
    return Status::InvalidArgument(fmt::format("params.{} = {} is outside [{}, {}]", range.name, value,
                                               static_cast<T>(range.min), static_cast<T>(range.max)));
  return Status::Ok();
}

Result<Iso3> RequestSeedPose(const pb::SeedPose& seed, FrameConvention* frame) {
  ARREF_ASSIGN_OR_RETURN(*frame, wire::FromProto(seed.frame()));
  return wire::PoseFromProto(seed.t_world_seed(), *frame);
}

}  // namespace

Result<RegistrationOptions> RequestOptions(const pb::RegisterRequest& m, const RegistrationOptions& configured) {
  RegistrationOptions o = configured;
  if (!m.method().empty()) {
    auto method = ParseMethod(m.method());
    if (!method.ok()) return method.status().WithContext("RegisterRequest.method");
    o.method = *method;
  }
  if (m.has_head_path()) {
    auto path = wire::HeadPathFromProto(m.head_path(), kMaxHeadPathPositions);
    if (!path.ok()) return path.status().WithContext("RegisterRequest");
    o.head_path_world = std::move(*path);
  }
  const pb::RegistrationParams& p = m.params();
  if (p.has_crop_radius_m()) {
    ARREF_RETURN_IF_ERROR(CheckRange(kCropRadiusRange, p.crop_radius_m()));
    o.crop_radius_m = p.crop_radius_m();
  }
  if (p.has_scene_samples()) {
    ARREF_RETURN_IF_ERROR(CheckRange(kSceneSamplesRange, p.scene_samples()));
    o.scene_samples = p.scene_samples();
  }
  if (p.has_icp_max_correspondence_m()) {
    ARREF_RETURN_IF_ERROR(CheckRange(kIcpMaxCorrespondenceRange, p.icp_max_correspondence_m()));
    o.icp.max_correspondence_m = p.icp_max_correspondence_m();
  }
  if (p.has_icp_max_iterations()) {
    ARREF_RETURN_IF_ERROR(CheckRange(kIcpMaxIterationsRange, p.icp_max_iterations()));
    o.icp.max_iterations = static_cast<int>(p.icp_max_iterations());
  }
  return o;
}

Result<JointValues> RequestJoints(const pb::RegisterRequest& m, const ServedRobot& robot, const RobotRegistry& robots,
                                  const SessionDefaults& session) {
  JointValues given;
  if (m.has_joints()) {
    auto j = wire::JointsFromProto(m.joints());
    if (!j.ok()) return j.status().WithContext("RegisterRequest.joints");
    given = std::move(*j);
  } else if (session.joints) {
    auto it = session.joints->find(m.robot_id());
    if (it == session.joints->end()) it = session.joints->find("");
    if (it != session.joints->end()) {
      if (!it->second.rejected.empty())
        return Status::InvalidArgument(fmt::format(
            "RegisterRequest: the session's latest JointState for robot '{}' was rejected ({}); the request does "
            "not run on other joints: send a valid JointState, or joints in the request",
            it->first.empty() ? "\"\" (every robot)" : it->first, it->second.rejected));
      given = it->second.values;
    }
  }
  auto joints = robots.ResolveJoints(robot, given);
  if (!joints.ok()) return joints.status().WithContext("joints");
  return joints;
}

Result<InstanceHint> RequestHint(const pb::RegisterRequest& m) {
  InstanceHint hint;
  if (!m.has_gaze_point() && !m.has_wearer_position()) return hint;
  FrameConvention frame = FrameConvention::kUnity;
  if (m.hint_frame() != pb::FRAME_CONVENTION_UNSPECIFIED) {
    auto f = wire::FromProto(m.hint_frame());
    if (!f.ok()) return f.status().WithContext("RegisterRequest.hint_frame");
    frame = *f;
  }
  auto point = [&](const pb::Vec3& v, const char* field) -> Result<Vec3> {
    const Vec3 p(v.x(), v.y(), v.z());
    if (!p.allFinite()) return Status::InvalidArgument(fmt::format("RegisterRequest.{} is not finite", field));
    return PositionToRos(p, frame);
  };
  if (m.has_gaze_point()) {
    ARREF_ASSIGN_OR_RETURN(hint.gaze_point_world, point(m.gaze_point(), "gaze_point"));
  }
  if (m.has_wearer_position()) {
    ARREF_ASSIGN_OR_RETURN(hint.wearer_position_world, point(m.wearer_position(), "wearer_position"));
  }
  return hint;
}

Result<std::shared_ptr<Job>> BuildJob(const pb::RegisterRequest& m, const RobotRegistry& robots,
                                      const RegistrationOptions& configured, const SessionDefaults& session) {
  const ServedRobot* robot = robots.Find(m.robot_id());
  if (!robot)
    return Status::NotFound(fmt::format("robot '{}' is not served here (served: {})", m.robot_id(), robots.Ids()));
  auto job = std::make_shared<Job>();
  FrameConvention frame = session.seed_frame;
  if (m.has_seed()) {
    auto T = RequestSeedPose(m.seed(), &frame);
    if (!T.ok()) return T.status().WithContext("RegisterRequest.seed");
    job->T_world_seed = *T;
  } else if (session.seed) {
    job->T_world_seed = *session.seed;
  } else if (!m.method().empty()) {
    // A named method: seedless ones search the whole map, seeded ones need the seed.
    auto method = ParseMethod(m.method());
    const MethodInfo* info = method.ok() ? FindMethod(*method) : nullptr;
    if (!info || !info->seedless)
      return Status::FailedPrecondition(fmt::format(
          "no seed: method '{}' needs one; send SeedPose (or RegisterRequest.seed), or name no method (or a seedless "
          "one) to search the whole map",
          m.method()));
    job->seedless = true;
  } else {
    job->seedless = true;  // the default with no seed: the whole map
  }
  ARREF_ASSIGN_OR_RETURN(job->joints, RequestJoints(m, *robot, robots, session));
  ARREF_ASSIGN_OR_RETURN(job->options, RequestOptions(m, configured));
  if (job->seedless && m.method().empty()) job->options.method = Method::kArrefAuto;
  if (const MethodInfo* info = FindMethod(job->options.method); info && info->seedless) job->seedless = true;
  ARREF_ASSIGN_OR_RETURN(job->hint, RequestHint(m));
  if (m.result_frame() != pb::FRAME_CONVENTION_UNSPECIFIED) {
    auto result_frame = wire::FromProto(m.result_frame());
    if (!result_frame.ok()) return result_frame.status().WithContext("RegisterRequest.result_frame");
    frame = *result_frame;
  }
  job->request_id = m.request_id();
  job->robot_id = m.robot_id();
  job->result_frame = frame;
  return job;
}

pb::ErrorCode RequestErrorCode(const Status& status) {
  switch (status.code()) {
    case StatusCode::kNotFound: return pb::ERROR_CODE_UNKNOWN_ROBOT;
    case StatusCode::kFailedPrecondition: return pb::ERROR_CODE_NO_SEED;
    default: return pb::ERROR_CODE_INVALID_ARGUMENT;
  }
}

JointStateOutcome ReadJointState(const pb::JointState& m, const RobotRegistry& robots) {
  const auto reject = [](pb::ErrorCode code, const std::string& why) {
    return JointStateOutcome{.keep = true, .joints = SessionJoints{.values = {}, .rejected = why}, .error = code,
                             .message = "JointState: " + why +
                                        "; requests that would use it fail until a valid JointState replaces it"};
  };
  auto joints = wire::JointsFromProto(m);
  if (!joints.ok()) return reject(pb::ERROR_CODE_INVALID_ARGUMENT, joints.status().message());
  if (!m.robot_id().empty()) {
    const ServedRobot* robot = robots.Find(m.robot_id());
    if (!robot)
      return JointStateOutcome{.keep = false, .joints = {}, .error = pb::ERROR_CODE_UNKNOWN_ROBOT,
                               .message = fmt::format("JointState: robot '{}' is not served here (served: {})",
                                                      m.robot_id(), robots.Ids())};
    auto checked = robots.ResolveJoints(*robot, *joints);
    if (!checked.ok()) return reject(pb::ERROR_CODE_INVALID_ARGUMENT, checked.status().message());
    return JointStateOutcome{.keep = true, .joints = SessionJoints{.values = std::move(*joints), .rejected = {}},
                             .complete = std::move(*checked)};
  }
  return JointStateOutcome{.keep = true, .joints = SessionJoints{.values = std::move(*joints), .rejected = {}}};
}

}  // namespace arref::server
