#include "tracking_messages.h"

#include <fmt/format.h>

#include <cmath>

#include "convert.h"

namespace arref::server {

namespace pb = wire::pb;

std::optional<Refusal> HandleTrackRequest(const pb::TrackRequest& m, const RobotRegistry& robots,
                                          TrackingService& tracking, const std::shared_ptr<TrackingSink>& session,
                                          const std::optional<Iso3>& session_seed) {
  const ServedRobot* robot = robots.Find(m.robot_id());
  if (!robot)
    return Refusal{pb::ERROR_CODE_UNKNOWN_ROBOT,
                   fmt::format("TrackRequest: robot '{}' is not served here (served: {})", m.robot_id(), robots.Ids())};
  if (m.stop()) {
    tracking.Stop(m.robot_id(), session->id());
    return std::nullopt;
  }
  const auto result_frame = wire::FromProto(m.result_frame());
  if (!result_frame.ok())
    return Refusal{pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.result_frame: " + result_frame.status().message()};
  std::optional<Iso3> seed = session_seed;
  if (m.has_seed()) {
    const auto frame = wire::FromProto(m.seed().frame());
    if (!frame.ok()) return Refusal{pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.seed: " + frame.status().message()};
    auto T = wire::PoseFromProto(m.seed().t_world_seed(), *frame);
    if (!T.ok()) return Refusal{pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.seed: " + T.status().message()};
    seed = *T;
  }
  if (!seed) return Refusal{pb::ERROR_CODE_NO_SEED, "TrackRequest: no seed in the request and no SeedPose in the session"};
  if (auto st = tracking.Start(*robot, m.robot_id(), session, *seed, *result_frame, m.camera_pose_latency_s()); !st.ok())
    return Refusal{wire::ErrorCodeFor(st), "TrackRequest: " + st.message()};
  return std::nullopt;
}

std::optional<Refusal> HandleDepthFrame(const pb::DepthFrame& m, TrackingService& tracking, std::uint64_t session_id) {
  auto frame = wire::DepthFrameFromProto(m);
  if (!frame.ok())
    return Refusal{pb::ERROR_CODE_BAD_DEPTH_FRAME, fmt::format("DepthFrame {}: {}", m.frame_id(), frame.status().message())};
  if (auto st = tracking.SubmitFrame(m.robot_id(), session_id, m.frame_id(), std::move(*frame)); !st.ok())
    return Refusal{pb::ERROR_CODE_NOT_TRACKING, st.message()};
  return std::nullopt;
}

std::optional<Refusal> HandleClockReport(const pb::ClockReport& m, TrackingService& tracking, std::uint64_t session_id) {
  if (!std::isfinite(m.offset_s()) || !std::isfinite(m.uncertainty_s()) || m.uncertainty_s() < 0)
    return Refusal{pb::ERROR_CODE_INVALID_ARGUMENT,
                   "ClockReport: offset and uncertainty must be finite, uncertainty >= 0"};
  tracking.ReportClock(session_id, {m.offset_s(), m.uncertainty_s(), true});
  return std::nullopt;
}

std::optional<Refusal> FeedJointStream(const pb::JointState& m, const JointValues& complete, TrackingService& tracking,
                                       std::uint64_t session_id) {
  if (m.robot_id().empty() || m.timestamp_s() <= 0) return std::nullopt;
  if (auto st = tracking.AddJoints(m.robot_id(), session_id, m.timestamp_s(), complete); !st.ok())
    return Refusal{pb::ERROR_CODE_INVALID_ARGUMENT, "JointState: " + st.message()};
  return std::nullopt;
}

}  // namespace arref::server
